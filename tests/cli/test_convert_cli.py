import json

import torch
from safetensors import safe_open

from lumos3d_cli.model.checkpoints import save_checkpoint
from lumos3d_cli.model.loading import load_model
from lumos3d_cli.model.lumos3d import build_model
from assertions import expect_input_error


def _random_checkpoint(path):
    return save_checkpoint(build_model("tiny", seed=3), path, {"weights": "random, for tests"})


def test_float16_halves_the_file_and_keeps_the_output(tmp_path, run_cli):
    source = _random_checkpoint(tmp_path / "full.safetensors")
    target = tmp_path / "half.safetensors"
    result = run_cli("convert", str(source), "-o", str(target), "--dtype", "float16", "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert summary["dtypes"] == {"F16": summary["tensors"]}
    assert summary["provenance"]["converted_from"] == {"file": "full.safetensors", "format": "lumos3d", "dtype": "float16"}
    assert 0.45 < target.stat().st_size / source.stat().st_size < 0.55
    with safe_open(str(target), framework="pt") as f:
        assert all(f.get_slice(key).get_dtype() == "F16" for key in f.keys())
    images = torch.rand(1, 2, 3, 28, 42, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        before, after = load_model(source)(images), load_model(target)(images)
    assert after.gaussians[0].means.dtype == torch.float32
    torch.testing.assert_close(after.depth, before.depth, rtol=1e-2, atol=1e-3)
    torch.testing.assert_close(after.extrinsics, before.extrinsics, rtol=1e-2, atol=1e-3)


def test_values_beyond_float16_are_refused(tmp_path, run_cli):
    model = build_model("tiny", seed=3)
    with torch.no_grad():
        next(model.parameters())[0].fill_(1e6)
    source = save_checkpoint(model, tmp_path / "big.safetensors")
    target = tmp_path / "half.safetensors"
    result = run_cli("convert", str(source), "-o", str(target), "--dtype", "float16")
    expect_input_error(result, "float16 range", "float32")
    assert not target.exists() and list(tmp_path.iterdir()) == [source]


def test_bad_arguments(tmp_path, run_cli):
    source = _random_checkpoint(tmp_path / "full.safetensors")
    expect_input_error(run_cli("convert", str(source), "-o", str(tmp_path / "x.safetensors"), "--dtype", "int8"), "int8", "float16")
    expect_input_error(run_cli("convert", str(source), "-o", str(tmp_path / "x.pt")), "x.pt", ".safetensors")
    expect_input_error(run_cli("convert", str(tmp_path / "none.pt"), "-o", str(tmp_path / "x.safetensors")), "none.pt")
