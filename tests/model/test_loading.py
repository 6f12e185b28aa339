import pytest

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.checkpoints import BUNDLED_MODELS, bundled_weights_path
from lumos3d_cli.model import loading
from lumos3d_cli.model.loading import load_model


@pytest.mark.parametrize("mode", list(BUNDLED_MODELS))
def test_a_bundled_model_loads_by_its_mode_name(mode):
    model = load_model(mode)
    assert model.provenance["path"] == str(bundled_weights_path(BUNDLED_MODELS[mode]))
    assert model.provenance["degradation"] == mode and not model.training


def test_a_missing_bundled_model_is_an_error_naming_the_file(monkeypatch, tmp_path):
    monkeypatch.setattr(loading, "bundled_weights_path", lambda name: tmp_path / f"{name}.safetensors")
    with pytest.raises(InputError) as error:
        load_model("low-light")
    assert str(tmp_path / "lumos3d-low-light.safetensors") in str(error.value)


def test_an_architecture_name_is_not_weights():
    with pytest.raises(InputError) as error:
        load_model("tiny")
    message = str(error.value)
    assert "architecture" in message and "build_model('tiny')" in message and "'low-light'" in message


def test_unknown_names_and_missing_files_are_errors():
    with pytest.raises(InputError, match="neither a checkpoint file nor a bundled model"):
        load_model("no-such-model")
    with pytest.raises(InputError, match="neither a checkpoint file nor a bundled model"):
        load_model("missing/model.safetensors")
