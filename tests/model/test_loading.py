import pytest

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.checkpoints import bundled_weights_path
from lumos3d_cli.model.loading import load_model


def test_a_preset_without_bundled_weights_is_an_error_naming_the_file():
    if bundled_weights_path("vggt-1b").exists():
        pytest.skip("vggt-1b weights are bundled in this installation")
    with pytest.raises(InputError) as error:
        load_model("vggt-1b")
    message = str(error.value)
    assert str(bundled_weights_path("vggt-1b")) in message and "build_model" in message


def test_unknown_names_and_missing_files_are_errors():
    with pytest.raises(InputError, match="neither a checkpoint file nor a preset"):
        load_model("no-such-model")
    with pytest.raises(InputError, match="neither a checkpoint file nor a preset"):
        load_model("missing/model.safetensors")
