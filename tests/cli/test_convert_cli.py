import json

import numpy as np
import torch
from safetensors import safe_open

from lumos3d_cli.io.ply import read_ply, write_ply
from lumos3d_cli.model.checkpoints import save_checkpoint
from lumos3d_cli.model.loading import load_model
from lumos3d_cli.model.lumos3d import build_model
from assertions import expect_input_error
from output_files import listing
from factories import random_gaussians


def _random_checkpoint(path):
    return save_checkpoint(build_model("tiny", seed=3), path, {"weights": "random, for tests"})


def test_float16_halves_the_file_and_keeps_the_output(tmp_path, run_cli):
    source = _random_checkpoint(tmp_path / "full.safetensors")
    target = tmp_path / "half.safetensors"
    result = run_cli("convert", str(source), "-o", str(target), "--dtype", "float16", "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert summary["dtypes"] == {"float16": summary["tensors"]}
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
    expect_input_error(result, f"{source}: tensor aggregator.camera_token holds values up to 1e+06, beyond the float16 range",
                       "float32")
    assert not target.exists() and list(tmp_path.iterdir()) == [source]


def test_bad_arguments(tmp_path, run_cli):
    source = _random_checkpoint(tmp_path / "full.safetensors")
    expect_input_error(run_cli("convert", str(source), "-o", str(tmp_path / "x.safetensors"), "--dtype", "int8"), "int8", "float16")
    result = run_cli("convert", str(source), "-o", str(tmp_path / "x.pt"))
    expect_input_error(result, f"{tmp_path / 'x.pt'}: checkpoints are written as .safetensors files")
    assert ".staging" not in result.err and not (tmp_path / "x.pt").exists()
    missing = run_cli("convert", str(tmp_path / "none.pt"), "-o", str(tmp_path / "x.safetensors"))
    expect_input_error(missing, f"error: {tmp_path / 'none.pt'}: no such file or folder")
    assert "--checkpoint" not in missing.err  # convert's source is an argument, not that option


# The .splat record as docs/formats.md describes it, written out here independently of io/splat.py.
SPLAT_RECORD = np.dtype([("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rotation", "u1", 4)])
C0 = 0.28209479177387814  # docs/formats.md: rgb = 0.5 + C0 * f_dc


def test_a_ply_scene_converts_to_splat(tmp_path, run_cli):
    original = random_gaussians(300, 2, seed=4)
    original.quats[7] = 0.0  # becomes the identity
    original.sh[:5, 0] = torch.tensor([4.0, -4.0, 0.0])  # rgb beyond [0, 1] is clipped
    write_ply(tmp_path / "scene.ply", original)
    scene = read_ply(tmp_path / "scene.ply")  # what the file holds (opacity and scale via logit/log)
    result = run_cli("convert", str(tmp_path / "scene.ply"), "-o", str(tmp_path / "scene.splat"), "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert summary["gaussians"] == 300 and summary["source_sh_degree"] == 2

    data = (tmp_path / "scene.splat").read_bytes()
    assert SPLAT_RECORD.itemsize == 32 and len(data) == 300 * 32 == summary["bytes"]
    records = np.frombuffer(data, SPLAT_RECORD)
    g = scene.to(torch.float64)
    order = torch.argsort(-(g.scales.prod(dim=1) * g.opacities), stable=True).numpy()  # decreasing volume x opacity
    np.testing.assert_array_equal(records["position"], scene.means.numpy()[order])
    np.testing.assert_array_equal(records["scale"], scene.scales.numpy()[order])
    rgba = np.concatenate([0.5 + C0 * g.sh[:, 0].numpy(), g.opacities.numpy()[:, None]], axis=1)
    np.testing.assert_array_equal(records["rgba"], np.clip(np.round(rgba * 255), 0, 255)[order])
    unit = torch.nn.functional.normalize(g.quats, dim=1).numpy()
    unit[7] = [1.0, 0.0, 0.0, 0.0]
    np.testing.assert_array_equal(records["rotation"], np.clip(np.round(unit * 128 + 128), 0, 255)[order])
    assert (records["rgba"][np.argsort(order)[:5], :3] == [255, 0, 128]).all()  # clipped, clipped, 0.5


def test_scene_and_checkpoint_suffixes_do_not_mix(tmp_path, run_cli):
    write_ply(tmp_path / "scene.ply", random_gaussians(4, 0))
    source = _random_checkpoint(tmp_path / "full.safetensors")
    expect_input_error(run_cli("convert", str(tmp_path / "scene.ply"), "-o", str(tmp_path / "x.safetensors")), "x.safetensors", ".splat")
    expect_input_error(run_cli("convert", str(source), "-o", str(tmp_path / "x.splat")), "full.safetensors", ".ply")
    expect_input_error(
        run_cli("convert", str(tmp_path / "scene.ply"), "-o", str(tmp_path / "x.splat"), "--dtype", "float16"), "--dtype", "checkpoints"
    )
    assert listing(tmp_path) == ["full.safetensors", "scene.ply"]


def test_an_empty_scene_is_not_converted(tmp_path, run_cli):
    write_ply(tmp_path / "empty.ply", random_gaussians(0, 0))
    expect_input_error(run_cli("convert", tmp_path / "empty.ply", "-o", tmp_path / "empty.splat"),
                       "empty.ply: holds no Gaussians; there is nothing to convert")
    assert listing(tmp_path) == ["empty.ply"]


def test_a_bundled_model_named_by_its_name_is_protected_as_an_input(tmp_path, run_cli, monkeypatch):
    """`convert low-light -o <the bundled file itself>` is refused as `convert <its path> -o <it>` is,
    even where lumos3d wrote that file (its manifest would otherwise let it be replaced)."""
    from lumos3d_cli.model import bundled_models

    weights = tmp_path / "weights"
    weights.mkdir()
    monkeypatch.setattr(bundled_models, "bundled_weights_path", lambda name: weights / f"{name}.safetensors")
    bundled = weights / f"{bundled_models.BUNDLED_MODELS['low-light']}.safetensors"
    assert run_cli("convert", str(_random_checkpoint(tmp_path / "full.safetensors")), "-o", str(bundled)).code == 0
    before = bundled.read_bytes()
    result = run_cli("convert", "low-light", "-o", str(bundled), "--dtype", "float16")
    expect_input_error(result, f"{bundled}: is an input")
    assert bundled.read_bytes() == before


def test_links_that_lead_round_in_a_loop_are_named(tmp_path, run_cli):
    """A looped .ply ended in an internal error (Path.resolve raises on a loop); a looped -o was
    called a link to a file "which does not exist"."""
    (tmp_path / "b.ply").symlink_to("a.ply")
    (tmp_path / "a.ply").symlink_to("b.ply")
    expect_input_error(run_cli("convert", tmp_path / "a.ply", "-o", tmp_path / "out.splat"),
                       f"{tmp_path / 'a.ply'}: its symbolic links lead round in a loop, to no file")
    write_ply(tmp_path / "scene.ply", random_gaussians(8, 0))
    (tmp_path / "d.splat").symlink_to("c.splat")
    (tmp_path / "c.splat").symlink_to("d.splat")
    expect_input_error(run_cli("convert", tmp_path / "scene.ply", "-o", tmp_path / "c.splat"),
                       "c.splat is a link to d.splat, whose links lead round in a loop")
    (tmp_path / "e.splat").symlink_to("f.splat")  # a chain of links that ends at nothing is no loop
    (tmp_path / "f.splat").symlink_to("nowhere.splat")
    expect_input_error(run_cli("convert", tmp_path / "scene.ply", "-o", tmp_path / "e.splat"),
                       "e.splat is a link to f.splat, which does not exist")
    assert listing(tmp_path) == ["a.ply", "b.ply", "c.splat", "d.splat", "e.splat", "f.splat", "scene.ply"]
