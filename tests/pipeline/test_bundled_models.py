"""The models shipped in src/lumos3d_cli/weights/: size, storage, provenance, and that they restore."""

import json
from pathlib import Path

import pytest
import torch
from safetensors import safe_open

from lumos3d_cli.io.images import load_images
from lumos3d_cli.model.bundled_models import BUNDLED_MODELS, bundled_weights_path
from lumos3d_cli.model.checkpoints import summarize_checkpoint

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "lowlight-buu"
WEIGHTS = {mode: bundled_weights_path(name) for mode, name in BUNDLED_MODELS.items()}


def test_the_bundled_models_fit_the_budget_in_half_precision():
    assert all(path.is_file() for path in WEIGHTS.values())
    assert sum(path.stat().st_size for path in WEIGHTS.values()) <= 30 * 2**20
    for mode, path in WEIGHTS.items():
        summary = summarize_checkpoint(path)
        # both predict a restoration operator (issue 15): an illumination head trained on brackets
        assert summary["format"] == "lumos3d" and summary["architecture"] == "tiny-operator"
        assert summary["dtypes"] == {"F16": summary["tensors"]}
        with safe_open(str(path), framework="pt") as f:
            assert all(torch.isfinite(f.get_tensor(key)).all() for key in f.keys())
        trained = summary["provenance"]
        assert trained["stage"] == "student" and trained["degradation"] == mode and trained["steps"] >= 500
        assert "lom" not in json.dumps(trained).lower()  # never trained on the evaluation set


@pytest.mark.parametrize("mode", ["low-light"])
def test_the_bundled_model_brightens_the_example_towards_normal_light(run_cli, buu, tmp_path, mode):
    out = tmp_path / "out" / "scene.ply"
    result = run_cli("restore", EXAMPLE, "-o", out, "--mode", mode, "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert summary["checkpoint"]["name"] == WEIGHTS[mode].name
    restored = load_images(out.parent / "restored").images
    inputs = load_images(EXAMPLE).images
    references = load_images([buu / "high" / f"{Path(name).stem}.JPG" for name in summary["views"]]).images
    references = torch.nn.functional.interpolate(references, size=restored.shape[-2:], mode="area")
    assert restored.mean() > 2 * inputs.mean()
    error_restored = (restored - references).abs().mean()
    error_inputs = (inputs - references).abs().mean()
    assert error_restored < 0.6 * error_inputs
