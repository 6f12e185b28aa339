import json
import shutil

import cv2
import numpy as np
import pytest
import trimesh
from assertions import expect_input_error
from plyfile import PlyData

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.camera_files import read_cameras
from lumos3d_cli.io.colmap import read_colmap_model
from lumos3d_cli.io.images import read_image
from lumos3d_cli.model import bundled_models
from lumos3d_cli.model.bundled_models import resolve_checkpoint
from lumos3d_cli.pipeline.network_pass import even_subset


def _copy(buu, tmp_path, names, folder="low"):
    target = tmp_path / "photos"
    target.mkdir(exist_ok=True)
    for name in names:
        shutil.copy(buu / folder / name, target / name)
    return target


def test_the_scores_against_references_are_said_on_the_console(run_cli, buu, tmp_path, random_checkpoint):
    """--reference DIR ("for PSNR/SSIM/LPIPS") put the scores in summary.json alone."""
    photos = _copy(buu, tmp_path, ["1.JPG", "2.JPG"])
    out = tmp_path / "out" / "scene.ply"
    result = run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--reference", buu / "high",
                     "--geometry", "network", "--refine-steps", 0)
    assert result.code == 0, result.err
    mean = json.loads((out.parent / "summary.json").read_text())["metrics"]["mean"]
    said = " ".join(result.err.split())
    assert f"against --reference: PSNR {mean['psnr']:.2f}, SSIM {mean['ssim']:.3f} (mean of the views" in said, said


def test_restore_writes_every_output(run_cli, buu, tmp_path, random_checkpoint):
    photos = _copy(buu, tmp_path, ["1.JPG", "2.JPG", "3.JPG"])
    out = tmp_path / "out" / "scene.ply"
    result = run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--reference", buu / "high",
                     "--geometry", "network", "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    ply = PlyData.read(str(out))
    vertex = ply["vertex"]
    assert vertex.count == summary["gaussians"]["kept"] > 0
    assert all(np.isfinite(vertex[p.name]).all() for p in vertex.properties)
    assert summary["gaussians"]["pixel"] == 3 * 224 * 168 and len(summary["network_views"]) == 3
    cameras = read_cameras(out.parent / "cameras.json")
    colmap = read_colmap_model(out.parent / "colmap")
    assert cameras.sizes == [(500, 375)] * 3 and cameras.names == ["1.JPG", "2.JPG", "3.JPG"]
    np.testing.assert_allclose(colmap.extrinsics.numpy(), cameras.extrinsics.numpy(), atol=1e-6)  # float32 network rotations
    np.testing.assert_allclose(colmap.intrinsics.numpy(), cameras.intrinsics.numpy(), atol=1e-9)
    for name in ("1", "2", "3"):
        assert cv2.imread(str(out.parent / "restored" / f"{name}.png")).shape == (375, 500, 3)
    assert cv2.imread(str(out.parent / "contact_sheet.png")) is not None
    glb = trimesh.load(str(out.parent / "preview.glb"))
    assert any(isinstance(g, trimesh.PointCloud) for g in glb.geometry.values())
    # glTF's COLOR_0 is linear: the points' colours are the Gaussians' sRGB colours decoded
    cloud = next(g for g in glb.geometry.values() if isinstance(g, trimesh.PointCloud))
    gaussians = PlyData.read(str(out))["vertex"]
    srgb = np.clip(0.5 + 0.28209479177387814 * np.stack([gaussians[f"f_dc_{c}"] for c in range(3)], axis=1), 0, 1)
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)  # IEC 61966-2-1
    assert abs(cloud.colors[:, :3].astype(float).mean() / 255 - linear.mean()) < 0.01
    assert abs(cloud.colors[:, :3].astype(float).mean() / 255 - srgb.mean()) > 0.05
    assert summary["metrics"]["mean"]["psnr"] > 0 and summary["metrics"]["mean"]["lpips"] is None
    assert "no LPIPS trunk weights" in summary["metrics"]["lpips_note"]
    assert len(summary["checkpoint"]["sha256"]) == 64 and set(summary["seconds"]) >= {"load", "network", "render", "write"}
    assert summary["geometry"]["source"] == "network"
    assert summary["input_paths"] == [str((photos / n).resolve()) for n in ("1.JPG", "2.JPG", "3.JPG")]
    budget = summary["gaussians"]["budget"]
    assert budget["kept"] == vertex.count and budget["max_gaussians"] is None and budget["capped"] == 0
    assert summary["gaussians"]["ply_mib"] == round(out.stat().st_size / 2**20, 3)


def test_max_gaussians_caps_the_scene(run_cli, buu, tmp_path, random_checkpoint):
    photos = _copy(buu, tmp_path, ["1.JPG", "2.JPG"])
    out = tmp_path / "out" / "scene.ply"
    result = run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--geometry", "network",
                     "--max-gaussians", "5000", "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    budget = summary["gaussians"]["budget"]
    assert PlyData.read(str(out))["vertex"].count == summary["gaussians"]["kept"] == budget["kept"] == 5000
    assert budget["max_gaussians"] == 5000 and budget["capped"] > 0
    assert summary["gaussians"]["voxels"] - summary["gaussians"]["pruned"] == (
        budget["kept"] + budget["dropped_unseen"] + budget["dropped_weak"] + budget["capped"])
    expect_input_error(run_cli("restore", photos, "-o", tmp_path / "bad" / "scene.ply", "--checkpoint", random_checkpoint,
                               "--max-gaussians", "0"), "--max-gaussians 0")
    assert not (tmp_path / "bad").exists()


def test_one_view_and_high_bit_depth_outputs(run_cli, buu, tmp_path, random_checkpoint):
    photos = _copy(buu, tmp_path, ["5.JPG"])
    for output_format, suffix in (("png16", ".png"), ("exr", ".exr")):
        out = tmp_path / output_format / "scene.ply"
        result = run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--output-format", output_format,
                         "--refine-steps", 0, "--quiet")
        assert result.code == 0, result.err
        written = read_image(out.parent / "restored" / f"5{suffix}")
        assert written.pixels.shape == (375, 500, 3) and written.pixels.dtype == np.float32
        assert (written.bit_depth, written.encoding) == ((16, "srgb") if output_format == "png16" else (16, "linear"))


def test_network_geometry_restores_only_the_views_the_network_saw(run_cli, buu, tmp_path, random_checkpoint):
    result = run_cli("restore", buu / "low", "-o", tmp_path / "o" / "scene.ply", "--checkpoint", random_checkpoint,
                     "--preset", "fast", "--max-views", 3, "--geometry", "network", "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert summary["views"] == summary["network_views"] == ["1.JPG", "13.JPG", "25.JPG"]
    said = " ".join(result.err.split())
    assert "22 view(s) have no camera and are not restored (the network did not see them; raise max_views or use " \
           "structure-from-motion)" in said


def test_restore_bad_inputs_leave_nothing(run_cli, buu, tmp_path, random_checkpoint):
    out = tmp_path / "out" / "scene.ply"
    empty = tmp_path / "empty"
    empty.mkdir()
    expect_input_error(run_cli("restore", empty, "-o", out, "--checkpoint", random_checkpoint), "folder holds no images")
    photos = _copy(buu, tmp_path, ["1.JPG", "2.JPG"])
    data = (buu / "low" / "3.JPG").read_bytes()
    (photos / "3.JPG").write_bytes(data[: len(data) // 2])
    expect_input_error(run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint), "3.JPG: cannot decode as JPG")
    (photos / "3.JPG").unlink()
    expect_input_error(run_cli("restore", photos, "-o", tmp_path / "o.obj", "--checkpoint", random_checkpoint), "must end in .ply")
    expect_input_error(run_cli("restore", photos, "-o", out, "--checkpoint", tmp_path / "none.safetensors"), "none.safetensors: no such")
    expect_input_error(run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--preset", "ultra"), "--preset 'ultra'")
    expect_input_error(run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--geometry", "colmap"),
                       "--geometry 'colmap': use one of auto, network, sfm")
    expect_input_error(run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--device", "tpu"),
                       "--device 'tpu': use cpu or cuda")
    small = tmp_path / "small"
    small.mkdir()
    for name in ("1", "2"):
        cv2.imwrite(str(small / f"{name}.png"), np.zeros((10, 10, 3), np.uint8))
    expect_input_error(run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--reference", small,
                               "--geometry", "network"),
                  f"{small / '1.png'}: 10x10, but input 1.JPG is 500x375; give references of the same size")
    result = run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--reference", small / "1.png")
    expect_input_error(result, f"--reference {small / '1.png'}: is a file, not a folder; give the folder of reference")
    assert not (tmp_path / "out").exists()


def test_missing_bundled_model_is_named(monkeypatch, tmp_path):
    monkeypatch.setattr(bundled_models, "bundled_weights_path", lambda name: tmp_path / f"{name}.safetensors")
    with pytest.raises(InputError, match="mode over-exposure: no bundled model .*give a checkpoint"):
        resolve_checkpoint(None, "over-exposure")


def test_even_subset_keeps_required_views():
    assert 5 in even_subset(10, 4, required=[5]) and len(even_subset(10, 4, required=[5])) == 4
    assert len(even_subset(10, 4, required=[1, 2])) == 4
    assert even_subset(3, 8) == [0, 1, 2]
    with pytest.raises(InputError, match="max_views 2: 3 views must go through the network"):
        even_subset(10, 2, required=[1, 2, 3])


def test_restore_writes_an_orbit_video(run_cli, buu, tmp_path, random_checkpoint):
    from lumos3d_cli.io.video import probe_video

    photos = _copy(buu, tmp_path, ["1.JPG", "2.JPG"])
    out = tmp_path / "out" / "scene.ply"
    expect_input_error(run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--video", tmp_path / "o.avi"),
                       ".mp4 (H.264) or .gif")
    assert not out.parent.exists()
    result = run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--geometry", "network",
                     "--refine-steps", 0, "--video", tmp_path / "orbit.mp4", "--quiet")
    assert result.code == 0, result.err
    stream = probe_video(tmp_path / "orbit.mp4")
    assert stream.codec == "h264" and stream.pixel_format == "yuv420p" and stream.width > 0
    video = json.loads((out.parent / "summary.json").read_text())["video"]  # what the file holds, as render --json says
    assert (video["codec"], video["width"], video["height"], video["frames"]) == ("h264", stream.width, stream.height, 120)
    assert video["path"] == str(tmp_path / "orbit.mp4") and video["filled"] is True
    # one photo: its view is the 2D restoration, but its orbit renders the scene, filled as well
    # (it was drawn over black, 38 % darker than the view)
    (tmp_path / "one").mkdir()
    one = _copy(buu, tmp_path / "one", ["1.JPG"])
    result = run_cli("restore", one, "-o", tmp_path / "one-out" / "scene.ply", "--video", tmp_path / "one.mp4",
                     "--refine-steps", 0, "--quiet")
    assert result.code == 0, result.err
    summary = json.loads((tmp_path / "one-out" / "summary.json").read_text())
    assert summary["restored_views"] == "photo restoration" and summary["video"]["filled"] is True
    result = run_cli("restore", one, "-o", tmp_path / "black-out" / "scene.ply", "--video", tmp_path / "black.mp4",
                     "--refine-steps", 0, "--black-unobserved", "--quiet")
    assert json.loads((tmp_path / "black-out" / "summary.json").read_text())["video"]["filled"] is False


def test_gaussian_grid_densifies_the_pixel_gaussians(run_cli, buu, tmp_path, random_checkpoint):
    photos = _copy(buu, tmp_path, ["1.JPG"])
    out = tmp_path / "out" / "scene.ply"
    result = run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--gaussian-grid", "2",
                     "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert summary["gaussians"]["budget"]["grid"] == [448, 336] and summary["gaussians"]["pixel"] == 448 * 336
    assert cv2.imread(str(out.parent / "restored" / "1.png")).shape == (375, 500, 3)
    expect_input_error(run_cli("restore", photos, "-o", tmp_path / "bad" / "scene.ply", "--checkpoint", random_checkpoint,
                               "--gaussian-grid", "0.5"), "--gaussian-grid 0.5")
    assert summary["exposure_prior"] is None  # a colour-regression model has no operator to expose
    assert summary["uncovered"]["filled"] and len(summary["uncovered"]["unobserved_fraction"]) == 1
    expect_input_error(run_cli("restore", photos, "-o", tmp_path / "bad" / "scene.ply", "--checkpoint", random_checkpoint,
                               "--exposure-prior", "2"), "--exposure-prior 2", "0 (the model's own exposure) to 1")
    expect_input_error(run_cli("restore", photos, "-o", tmp_path / "bad" / "scene.ply", "--checkpoint", random_checkpoint,
                               "--exposure-key", "sunny"), "--exposure-key", "content, fixed")
    assert not (tmp_path / "bad").exists()


def _restore_filled_or_black(run_cli, photos, tmp_path, checkpoint, flag: str, steps: int) -> tuple[dict, np.ndarray]:
    """`restore` of `photos` (`fast`, the network's cameras, `steps` refinement steps) with `flag`
    (--fill-unobserved or --black-unobserved) -> (its summary, restored view 1.png as int BGR)."""
    out = tmp_path / flag.strip("-") / "scene.ply"
    result = run_cli("restore", photos, "-o", out, "--checkpoint", checkpoint, "--geometry", "network",
                     "--preset", "fast", "--refine-steps", steps, flag, "--json")
    assert result.code == 0, result.err
    return json.loads(result.out), cv2.imread(str(out.parent / "restored" / "1.png")).astype(int)


def test_refinement_fits_the_views_as_they_are_shown(run_cli, buu, tmp_path, random_checkpoint):
    """Filled views: refinement fits the renders divided by their alpha (what the fill shows);
    black views: the render over black."""
    photos = _copy(buu, tmp_path, ["1.JPG", "2.JPG"])
    fitted = {flag: _restore_filled_or_black(run_cli, photos, tmp_path, random_checkpoint, flag, 2)[0]["refinement"]["fitted"]
              for flag in ("--fill-unobserved", "--black-unobserved")}
    assert fitted == {"--fill-unobserved": "splat colours", "--black-unobserved": "over black"}


def test_uncovered_pixels_are_filled_unless_asked_to_stay_black(run_cli, buu, tmp_path, random_checkpoint):
    photos = _copy(buu, tmp_path, ["1.JPG", "2.JPG"])
    views = {}
    for flag in ("--fill-unobserved", "--black-unobserved"):
        summary, view = _restore_filled_or_black(run_cli, photos, tmp_path, random_checkpoint, flag, 0)
        views[flag] = (summary["uncovered"], view)
    (filled, filled_view), (black, black_view) = views["--fill-unobserved"], views["--black-unobserved"]
    assert filled["filled"] and not black["filled"]
    assert filled["unobserved_fraction"] == black["unobserved_fraction"]  # the same scene, only the compositing differs
    assert (filled_view >= black_view - 1).all()  # filling adds (1 - alpha) x colour: it never darkens
    if black["unobserved_fraction"][0] > 0.001:
        assert np.abs(filled_view - black_view).max() > 12


def test_the_output_folder_is_held_before_structure_from_motion_starts(run_cli, buu, tmp_path, monkeypatch):
    """The lock was taken after structure-from-motion had started: a second run into the same
    folder was refused only when the first reached its network pass, a minute of duplicated work."""
    from lumos3d_cli.io.output_lock import LOCK_NAME
    from lumos3d_cli.pipeline import early_registration

    photos = _copy(buu, tmp_path, ["1.JPG", "2.JPG", "3.JPG"])
    out = tmp_path / "out"
    held = []

    def observed(*args, **kwargs):
        held.append((out / LOCK_NAME).is_file())
        raise InputError("stopped here by the test")

    monkeypatch.setattr(early_registration, "start_early_registration", observed)
    expect_input_error(run_cli("restore", photos, "-o", out / "scene.ply"), "stopped here by the test")
    assert held == [True] and not out.exists()  # held then, and the folder it made is gone again
    # a video the tool cannot write is refused before structure-from-motion starts (4-7 s into it)
    expect_input_error(run_cli("restore", photos, "-o", out / "scene.ply", "--video", tmp_path / "orbit.webm"), "webm")
    assert held == [True] and not out.exists()
