"""Test-time refinement inside the restore and eval jobs (pipeline/scene_refinement.py)."""

import json
import shutil
from dataclasses import replace

import pytest
import torch
import torch.nn.functional as F
from assertions import expect_input_error

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.images import load_images
from lumos3d_cli.model.lumos3d import build_model
from lumos3d_cli.pipeline.network_pass import run_network
from lumos3d_cli.pipeline.presets import DEPTH_SWEEP, REFINE_LR_DECAY, RESTORE_PRESETS, get_restore_preset
from lumos3d_cli.pipeline.scene_refinement import network_colours, refinement_targets
from lumos3d_cli.pipeline.scene_stages import build_scene, refinement


def _photos(buu, tmp_path, names):
    target = tmp_path / "photos"
    target.mkdir()
    for name in names:
        shutil.copy(buu / "low" / name, target / name)
    return target


def test_restore_refines_and_reports_the_loss_curve(run_cli, buu, tmp_path, random_checkpoint):
    photos = _photos(buu, tmp_path, ["1.JPG", "2.JPG", "3.JPG"])
    result = run_cli("restore", photos, "-o", tmp_path / "out" / "scene.ply", "--checkpoint", random_checkpoint,
                     "--geometry", "network", "--refine-steps", 4, "--json")
    assert result.code == 0, result.err
    refinement = json.loads(result.out)["refinement"]
    assert refinement["steps"] == 4 and len(refinement["loss_curve"]) == 4
    assert all(value > 0 for value in refinement["loss_curve"]) and refinement["sh_degree"] in (0, 1)
    assert refinement["working_size"] == [500, 375]  # balanced (the default) fits the photos' own size
    fast = run_cli("restore", photos, "-o", tmp_path / "fast" / "scene.ply", "--checkpoint", random_checkpoint,
                   "--geometry", "network", "--preset", "fast", "--refine-steps", 2, "--json")
    assert json.loads(fast.out)["refinement"]["working_size"] == [256, 192]  # fast downsamples to refine's 256 px
    # every preset's learning rates decay, and summary.json says by how much
    assert refinement["lr_decay_per_100_steps"] == json.loads(fast.out)["refinement"]["lr_decay_per_100_steps"]
    assert refinement["lr_decay_per_100_steps"] == pytest.approx(REFINE_LR_DECAY) and REFINE_LR_DECAY < 1
    plain = run_cli("restore", photos, "-o", tmp_path / "plain" / "scene.ply", "--checkpoint", random_checkpoint,
                    "--geometry", "network", "--preset", "fast", "--refine-steps", 0, "--json")
    assert json.loads(plain.out)["refinement"] is None  # 0 steps: the forward pass as it is


def test_restore_densifies_within_the_gaussian_cap(run_cli, buu, tmp_path, random_checkpoint):
    """`--densify` splits and clones during refinement and says so in summary.json; the scene
    never exceeds `--max-gaussians` (checked in the written .ply with plyfile)."""
    from plyfile import PlyData

    photos = _photos(buu, tmp_path, ["1.JPG", "2.JPG"])
    common = ["--checkpoint", random_checkpoint, "--geometry", "network", "--preset", "fast", "--refine-steps", 20,
              "--json"]
    grown = run_cli("restore", photos, "-o", tmp_path / "grown" / "scene.ply", "--densify", *common)
    assert grown.code == 0, grown.err
    summary = json.loads(grown.out)
    steps = summary["refinement"]["densification"]
    assert [step["step"] for step in steps] == [10]  # not at step 20: nothing would fit what it made
    assert summary["gaussians"]["kept"] == steps[-1]["gaussians"] == len(PlyData.read(tmp_path / "grown" / "scene.ply")["vertex"])
    assert steps[0]["split"] + steps[0]["cloned"] > 0
    start = steps[0]["gaussians"] - steps[0]["split"] - steps[0]["cloned"] + steps[0]["pruned"]
    cap = start + 10
    capped = run_cli("restore", photos, "-o", tmp_path / "capped" / "scene.ply", "--densify", "--max-gaussians", cap, *common)
    assert capped.code == 0, capped.err
    assert len(PlyData.read(tmp_path / "capped" / "scene.ply")["vertex"]) <= cap
    plain = run_cli("restore", photos, "-o", tmp_path / "plain" / "scene.ply", "--no-densify", *common)
    assert json.loads(plain.out)["refinement"]["densification"] == []


def test_refine_steps_are_checked(run_cli, buu, tmp_path, random_checkpoint):
    photos = _photos(buu, tmp_path, ["1.JPG"])
    expect_input_error(run_cli("restore", photos, "-o", tmp_path / "o" / "scene.ply", "--checkpoint", random_checkpoint,
                               "--refine-steps", -1), "--refine-steps -1")
    assert not (tmp_path / "o").exists()


def test_presets_refine_more_as_they_slow_down_and_the_option_overrides():
    steps = [RESTORE_PRESETS[name].refine_steps for name in ("fast", "balanced", "best")]
    assert 0 < steps[0] < steps[1] < steps[2]
    assert get_restore_preset("best", 0).refine_steps == 0 and get_restore_preset("fast", 7).refine_steps == 7
    assert get_restore_preset("fast", densify=True).densify is not None
    assert get_restore_preset("best", densify=False).densify is None
    assert all(RESTORE_PRESETS[name].depth_sweep == DEPTH_SWEEP for name in ("fast", "balanced", "best"))
    assert get_restore_preset("fast", depth_sweep=False).depth_sweep is None
    assert get_restore_preset("fast", depth_sweep=True).depth_sweep == DEPTH_SWEEP
    assert get_restore_preset("balanced", depth_sweep=False).depth_sweep is None


def test_balanced_fits_every_view_at_least_once_unless_told_the_steps(buu):
    """A scene of more views than the preset's steps refines one step per view (each view fitted
    once), up to twice the preset's steps; `--refine-steps N` (get_restore_preset's refine_steps)
    means exactly N."""
    assert get_restore_preset("balanced").refine_each_view and not get_restore_preset("fast").refine_each_view
    assert not get_restore_preset("balanced", refine_steps=45).refine_each_view
    balanced = get_restore_preset("balanced")
    assert [balanced.refinement_steps(views) for views in (3, 45, 60, 120)] == [45, 45, 60, 90]  # capped at twice
    assert get_restore_preset("fast").refinement_steps(64) == 15
    names = ["1.JPG", "2.JPG", "3.JPG", "4.JPG", "5.JPG"]
    photos = torch.stack([load_images([buu / "low" / name]).images[0] for name in names])
    model = build_model("tiny-operator", seed=0).eval()
    each_view = replace(get_restore_preset("balanced"), refine_steps=3, refine_side=64)
    job = build_scene(photos, names, model, replace(each_view, refine_steps=0), geometry="network")
    fused = job.gaussians
    for preset, steps in ((each_view, 5), (replace(each_view, refine_each_view=False), 3)):
        job.preset, job.gaussians = preset, fused
        assert refinement(job).refinement["steps"] == steps


def test_targets_leave_out_held_out_views_and_follow_the_cameras(buu):
    model = build_model("tiny", seed=0).eval()
    photos = torch.rand(3, 3, 42, 56, generator=torch.Generator().manual_seed(0))
    network = run_network(model, photos, get_restore_preset("fast"))
    names = ["a.png", "b.png", "c.png"]
    cameras = Cameras(torch.eye(4)[:3].repeat(3, 1, 1), torch.eye(3).repeat(3, 1, 1), [(56, 42)] * 3, ["c.png", "a.png", "b.png"])
    restored = torch.stack([torch.full((3, 42, 56), float(i)) for i in range(3)])
    targets, fitted = refinement_targets(network, model, photos, restored, [0, 1, 2], names, cameras, [True, False, True])
    assert fitted.names == ["c.png", "a.png"]  # in the cameras' order, b held out
    assert torch.equal(targets[:, 0, 0, 0], torch.tensor([2.0, 0.0]))
    # a regression model has targets only for the views the network saw: its own colours
    targets, fitted = refinement_targets(network, model, photos, None, [0, 2], ["a.png", "b.png", "c.png"], cameras, None)
    assert fitted.names == ["c.png", "a.png"] and targets.shape == (2, 3, 42, 56)
    colours = network_colours(network, model, (42, 56))
    assert torch.equal(targets[1], colours[0]) and 0 <= float(colours.min()) <= float(colours.max()) <= 1
    # at refinement's working size: the full-size stack was a third full-resolution copy of the photos
    restored = torch.rand(3, 3, 42, 56, generator=torch.Generator().manual_seed(1))
    targets, fitted = refinement_targets(network, model, photos, restored, [0, 1, 2], names, cameras, None, max_side=28)
    assert targets.shape == (3, 3, 21, 28) and fitted.sizes == cameras.sizes  # refinement rescales the cameras
    torch.testing.assert_close(targets[1], F.interpolate(restored[None, 0], size=(21, 28), mode="area")[0])


@pytest.mark.parametrize("steps", [0, 3])
def test_a_single_photo_refines_or_not_and_stays_finite(run_cli, buu, tmp_path, random_checkpoint, steps):
    photos = _photos(buu, tmp_path, ["5.JPG"])
    result = run_cli("restore", photos, "-o", tmp_path / "out" / "scene.ply", "--checkpoint", random_checkpoint,
                     "--refine-steps", steps, "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert (summary["refinement"] is None) == (steps == 0)
