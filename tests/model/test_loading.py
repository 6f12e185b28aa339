import pytest

from lumos3d_cli.errors import InputError
from lumos3d_cli.model import bundled_models
from lumos3d_cli.model.bundled_models import BUNDLED_MODELS, bundled_weights_path, resolve_checkpoint
from lumos3d_cli.model.loading import load_model


@pytest.mark.parametrize("mode", list(BUNDLED_MODELS))
def test_a_bundled_model_loads_by_its_mode_name(mode):
    model = load_model(mode)
    assert model.provenance["path"] == str(bundled_weights_path(BUNDLED_MODELS[mode]))
    assert model.provenance["degradation"] == mode and not model.training


@pytest.mark.parametrize("mode", list(BUNDLED_MODELS))
def test_one_resolver_maps_a_mode_a_bundled_name_or_a_path_to_the_weights(mode, tmp_path):
    bundled = bundled_weights_path(BUNDLED_MODELS[mode])
    assert resolve_checkpoint(None, mode) == resolve_checkpoint(mode) == bundled and bundled.is_file()
    assert resolve_checkpoint(tmp_path, mode) == tmp_path  # a given checkpoint wins over the mode
    (tmp_path / mode).mkdir()
    assert resolve_checkpoint(tmp_path / mode) == tmp_path / mode


def test_a_missing_bundled_model_is_an_error_naming_the_file(monkeypatch, tmp_path):
    monkeypatch.setattr(bundled_models, "bundled_weights_path", lambda name: tmp_path / f"{name}.safetensors")
    with pytest.raises(InputError) as error:
        load_model("low-light")
    assert str(tmp_path / "lumos3d-low-light.safetensors") in str(error.value)
    with pytest.raises(InputError, match="^mode over-exposure: no bundled model .*give a checkpoint") as error:
        resolve_checkpoint(None, "over-exposure")
    assert error.value.with_option("--mode").startswith("--mode over-exposure: ")


def test_an_architecture_name_is_not_weights():
    with pytest.raises(InputError) as error:
        load_model("tiny")
    message = str(error.value)
    assert message.startswith("checkpoint tiny: ")
    assert "architecture" in message and "build_model('tiny')" in message and "'low-light'" in message


def test_unknown_names_missing_files_and_modes_name_the_parameter():
    with pytest.raises(InputError, match="^checkpoint no-such-model: no such file or folder, and not a bundled model") as error:
        load_model("no-such-model")
    assert error.value.with_option("--checkpoint").startswith("--checkpoint no-such-model: no such file")
    with pytest.raises(InputError, match="^checkpoint missing/model.safetensors: no such file or folder"):
        load_model("missing/model.safetensors")
    with pytest.raises(InputError, match="^mode 'dusk': no bundled model for it; use one of 'low-light', 'over-exposure'"):
        resolve_checkpoint(None, "dusk")


def test_a_device_this_machine_lacks_is_refused_by_name_before_the_weights_load(monkeypatch):
    import torch

    for device, message in (("bogus", "^device 'bogus': not a device; use cpu or cuda$"),
                            ("meta", "^device meta: lumos3d runs on cpu or cuda$")):
        with pytest.raises(InputError, match=message):
            load_model("low-light", device=device)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    with pytest.raises(InputError, match="^device cuda:1: this machine has 1 CUDA device"):
        load_model("low-light", device="cuda:1")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    for device in ("cuda", torch.device("cuda:0")):
        with pytest.raises(InputError, match="CUDA is not available on this machine; use cpu$"):
            load_model("low-light", device=device)


def test_a_training_run_folder_points_to_its_weights(tmp_path, random_checkpoint):
    import shutil

    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text("{}")
    with pytest.raises(InputError, match="a training run's folder, not a checkpoint; give one of its checkpoints/step_"):
        load_model(run)
    shutil.copy(random_checkpoint, run / "final.safetensors")
    with pytest.raises(InputError, match=f"give {run / 'final.safetensors'}"):
        load_model(run)
