"""Structure-from-motion started before torch is imported (pipeline/early_registration.py): the
same photos and the same cameras as the job's own run (the oracle: register_views on the main
thread, one matching thread, which repeats exactly), no torch imported on the way, errors that
reach the caller as the job's own, and only where the job would brighten with the tone curve."""

import json
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from assertions import expect_input_error
from processes import interrupt_when

from lumos3d_cli import build_model, load_images
from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.colmap_run import ColmapStopped
from lumos3d_cli.io.colour import srgb_to_linear
from lumos3d_cli.io.image_write import write_exr
from lumos3d_cli.pipeline.early_registration import EarlyRegistration, start_early_registration
from lumos3d_cli.pipeline.presets import get_restore_preset
from lumos3d_cli.pipeline.progress import SilentProgress
from lumos3d_cli.pipeline.scene_geometry import register_views
from lumos3d_cli.pipeline.scene_stages import build_scene

NAMES = ["3.JPG", "4.JPG", "5.JPG", "6.JPG", "7.JPG"]


def _fast(**changes):
    return replace(get_restore_preset("fast", refine_steps=0), **changes)


def test_the_job_takes_photos_and_cameras_from_the_early_run_unchanged(buu):
    paths = [buu / "low" / name for name in NAMES]
    early = EarlyRegistration(paths, _fast().sfm_long_side)
    decoded = np.stack([cv2.imread(str(path))[..., ::-1].transpose(2, 0, 1) for path in paths]) / 255.0
    assert np.abs(early.photos().pixels - decoded).max() < 1e-6  # the photos as OpenCV decodes them
    batch = load_images(paths)
    model = build_model("tiny-operator", seed=0).eval()
    built = build_scene(early.photos().batch().images, NAMES, model, _fast(), geometry="sfm", max_views=3,
                        early_registration=early)
    assert built.geometry.summary()["registered_views"] == 5
    direct = register_views(batch.images, NAMES, "sfm", None, SilentProgress(), sfm_long_side=384)
    assert torch.equal(built.registration.cameras.extrinsics, direct.cameras.extrinsics)
    assert torch.equal(built.registration.cameras.intrinsics, direct.cameras.intrinsics)
    assert torch.equal(built.registration.sfm.points.xyz, direct.sfm.points.xyz)


def test_the_photos_are_brightened_one_at_a_time_as_colmap_reads_them(buu, monkeypatch):
    """Brightened at once, they were a full-resolution copy of every photo held through the whole
    registration (3.6 GB for 25 photos of 12 MP); the cameras are the same (the test above)."""
    from lumos3d_cli.pipeline import early_registration as module

    shapes = []
    original = module.auto_gamma_array

    def recording(pixels):
        shapes.append(pixels.shape)
        return original(pixels)

    monkeypatch.setattr(module, "auto_gamma_array", recording)
    early = EarlyRegistration([buu / "low" / name for name in NAMES], _fast().sfm_long_side)
    assert early.colmap_run().models
    assert len(shapes) >= len(NAMES) and all(shape == (3, 375, 500) for shape in shapes)


def test_the_early_run_imports_no_torch(buu):
    script = f"""
import sys
from pathlib import Path
from lumos3d_cli.pipeline.early_registration import EarlyRegistration
from lumos3d_cli.pipeline.presets import get_restore_preset
early = EarlyRegistration([Path({str(buu / "low")!r}) / name for name in {NAMES!r}], get_restore_preset("fast").sfm_long_side)
run = early.colmap_run()
print(max(model.num_reg_images() for model in run.models), "torch" in sys.modules)
"""
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert result.stdout.split() == ["5", "False"]


def test_linear_photos_register_while_torch_is_being_imported(buu, tmp_path):
    """EXR photos go through the checks and colour code that take tensors too; torch's import in
    the main thread (its module half-made meanwhile) must not break them."""
    for name in NAMES:
        srgb = cv2.imread(str(buu / "low" / name))[..., ::-1].astype(np.float32) / 255
        write_exr(tmp_path / f"{Path(name).stem}.exr", srgb_to_linear(srgb))
    script = f"""
from pathlib import Path
from lumos3d_cli.pipeline.early_registration import EarlyRegistration
early = EarlyRegistration(sorted(Path({str(tmp_path)!r}).glob("*.exr")), 384)
import torch
print(max(model.num_reg_images() for model in early.colmap_run().models))
"""
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert result.returncode == 0 and result.stdout.split() == ["5"], result.stderr


def test_an_unreadable_photo_reaches_the_caller_from_both_parts(buu, tmp_path):
    (tmp_path / "1.JPG").write_bytes((buu / "low" / "1.JPG").read_bytes())
    data = (buu / "low" / "2.JPG").read_bytes()
    (tmp_path / "2.JPG").write_bytes(data[: len(data) // 2])
    early = EarlyRegistration([tmp_path / "1.JPG", tmp_path / "2.JPG"], 384)
    for wait in (early.photos, early.colmap_run):
        with pytest.raises(InputError, match="2.JPG: cannot decode as JPG"):
            wait()


def test_the_cli_refuses_an_unreadable_photo_with_one_line(run_cli, buu, tmp_path, random_checkpoint):
    photos = tmp_path / "photos"
    photos.mkdir()
    (photos / "1.JPG").write_bytes((buu / "low" / "1.JPG").read_bytes())
    data = (buu / "low" / "2.JPG").read_bytes()
    (photos / "2.JPG").write_bytes(data[: len(data) // 2])
    out = tmp_path / "out" / "scene.ply"
    expect_input_error(run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--preset", "fast"),
                       "2.JPG: cannot decode as JPG")
    assert not out.parent.exists()


def test_a_fast_restore_registers_with_the_early_run(run_cli, buu, tmp_path, random_checkpoint):
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in NAMES:
        (photos / name).write_bytes((buu / "low" / name).read_bytes())
    out = tmp_path / "out" / "scene.ply"
    result = run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--preset", "fast",
                     "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    geometry = json.loads(result.out)["geometry"]
    assert geometry["source"] == "sfm" and geometry["registered_views"] == 5
    assert geometry["brightening"].startswith("auto-gamma") and geometry["sfm_size"] == [384, 288]


def test_only_where_the_job_would_brighten_with_the_tone_curve(buu):
    paths = [buu / "low" / name for name in NAMES[:2]]
    fast = get_restore_preset("fast")
    assert start_early_registration(paths, get_restore_preset("balanced"), "auto", None) is None  # sees the restoration
    assert start_early_registration(paths, fast, "network", None) is None
    assert start_early_registration(paths, fast, "auto", buu / "transforms_train.json") is None
    assert start_early_registration(paths[:1], fast, "auto", None) is None
    early = start_early_registration(paths, fast, "sfm", None)
    assert isinstance(early, EarlyRegistration) and early.long_side == fast.sfm_long_side
    early.colmap_run()


def test_an_early_run_of_other_photos_or_size_is_refused(buu):
    paths = [buu / "low" / name for name in NAMES[:2]]
    early = EarlyRegistration(paths, 512)
    photos = early.photos().batch().images
    model = build_model("tiny-operator", seed=0).eval()
    with pytest.raises(ValueError, match="other photos or another size"):
        build_scene(photos, NAMES[:2], model, _fast(), geometry="sfm", early_registration=early)
    with pytest.raises(ValueError, match="other photos or another size"):
        build_scene(photos, ["a.JPG", "b.JPG"], model, _fast(sfm_long_side=512), geometry="sfm",
                    early_registration=early)
    early.colmap_run()


def test_closing_stops_colmap_within_its_stage_and_leaves_no_work_folder(buu, tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    early = EarlyRegistration(sorted((buu / "low").iterdir()), 384)
    assert early.photos().pixels.shape[0] == 25
    while not any(tmp_path.glob("lumos3d-sfm-*/database.db")):  # COLMAP is at work
        time.sleep(0.01)
    started = time.perf_counter()
    early.close()
    assert time.perf_counter() - started < 1.5  # not the 3-4 s the run takes
    with pytest.raises(ColmapStopped):
        early.colmap_run()
    assert list(tmp_path.iterdir()) == []


def test_closing_while_the_photos_are_read_stops_the_reading(buu, tmp_path, monkeypatch):
    photos = tmp_path / "photos"
    photos.mkdir()
    for copy in range(8):  # 200 photos: about 1 s to read
        for path in sorted((buu / "low").iterdir()):
            (photos / f"{copy}-{path.name}").write_bytes(path.read_bytes())
    work = tmp_path / "tmp"
    work.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(work))
    early = EarlyRegistration(sorted(photos.iterdir()), 384)
    early.close()
    with pytest.raises(ColmapStopped):
        early.photos()
    assert list(work.iterdir()) == []


def test_a_fast_command_refused_after_the_start_leaves_no_work_folder(run_cli, buu, tmp_path, random_checkpoint,
                                                                    monkeypatch):
    work = tmp_path / "tmp"
    work.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(work))
    out = tmp_path / "out" / "scene.ply"
    for option, value, message in (("--max-views", 0, "use at least 1"), ("--mode", "dusk", "'dusk'"),
                                   ("--checkpoint", tmp_path / "none.safetensors", "no such")):
        arguments = ["--checkpoint", random_checkpoint] if option != "--checkpoint" else []
        expect_input_error(run_cli("restore", buu / "low", "-o", out, "--preset", "fast", option, value, *arguments),
                           message)
        assert list(work.iterdir()) == [] and not out.parent.exists()
        assert not any(thread.name == "lumos3d-early-sfm" for thread in threading.enumerate())  # closed, not left running


def test_ctrl_c_while_colmap_runs_exits_130_and_leaves_no_work_folder(buu, tmp_path, random_checkpoint):
    work = tmp_path / "tmp"
    work.mkdir()
    out = tmp_path / "out" / "scene.ply"
    result = interrupt_when(("restore", buu / "low", "-o", out, "--checkpoint", random_checkpoint, "--preset", "fast"),
                            lambda _: any(work.glob("lumos3d-sfm-*")), signal.SIGINT, env={"TMPDIR": str(work)})
    assert result.code == 130 and result.last_line.startswith("interrupted by SIGINT"), result.err[-2000:]
    assert list(work.iterdir()) == [] and not out.parent.exists()
