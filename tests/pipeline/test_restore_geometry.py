"""`restore` with registered geometry: structure-from-motion, given poses, and what happens when
neither can place the photos."""

import json
import re
import shutil

import cv2
import numpy as np
import pytest
import torch
from assertions import expect_input_error
from plyfile import PlyData

from lumos3d_cli.data.lom import lom_reference_extrinsics, read_lom_scene
from lumos3d_cli.io.camera_files import read_cameras
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.colmap import read_colmap_model, read_colmap_points
from lumos3d_cli.io.transforms_json import read_transforms_json, write_transforms_json

FRAMES = ["3.JPG", "4.JPG", "5.JPG", "6.JPG", "7.JPG"]


def _photos(buu, tmp_path, names=FRAMES, folder="low"):
    target = tmp_path / "photos"
    target.mkdir(parents=True, exist_ok=True)
    for name in names:
        shutil.copy(buu / folder / name, target / name)
    return target


# The presets' speed settings: the size SfM sees buu's 500x375 photos at, and the scale the
# Gaussian budget renders its weights at (`balanced` has fast's SfM size and best's budget); the
# smaller settings must still place the cameras as well.
@pytest.mark.parametrize("preset, sfm_size, weights_resolution", [("best", [500, 375], 1.0), ("fast", [384, 288], 0.5)])
def test_sfm_registers_the_photos_and_writes_a_colmap_model_with_points(run_cli, buu, tmp_path, random_checkpoint,
                                                                         preset, sfm_size, weights_resolution):
    photos = _photos(buu, tmp_path)
    out = tmp_path / "out" / "scene.ply"
    result = run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--geometry", "sfm",
                     "--max-views", 3, "--preset", preset, "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    geometry = summary["geometry"]
    assert geometry["sfm_size"] == sfm_size and summary["gaussians"]["budget"]["weights_resolution"] == weights_resolution
    assert geometry["source"] == "sfm" and geometry["registered_views"] == 5 and geometry["sparse_points"] > 50
    assert geometry["reprojection_error_px"] < 2 and geometry["brightening"].startswith("auto-gamma")
    assert 0 <= geometry["depth_consistency"] <= 1 and geometry["depth_alignment"]["views"] == 3
    # every preset sweeps the registered depth against the neighbouring photos
    sweep = geometry["depth_sweep"]
    assert 0 <= sweep["changed_pixels"] <= 1 and sweep["hypotheses"] % 2 == 1 and sweep["window_px"] == 7
    assert set(summary["seconds"]) >= {"sfm", "network", "fuse", "render"}
    # every photo is restored although the network saw three of them
    assert summary["views"] == FRAMES and len(summary["network_views"]) == 3
    assert sorted(p.name for p in (out.parent / "restored").iterdir()) == [f"{n[:-4]}.png" for n in FRAMES]
    colmap = read_colmap_model(out.parent / "colmap")
    points = read_colmap_points(out.parent / "colmap" / "points3D.txt")
    assert colmap.names == FRAMES and len(points.xyz) == geometry["sparse_points"]
    # the registered cameras against the scene's own: relative rotations within a few degrees
    reference = lom_reference_extrinsics(read_lom_scene(buu, "low-light"))
    truth = torch.stack([reference[n[:-4]] for n in FRAMES]).double()
    ours = colmap.extrinsics.double()
    for i in range(1, 5):
        relative = lambda e: e[i, :, :3] @ e[0, :, :3].T  # noqa: E731
        cosine = ((relative(ours).T @ relative(truth)).trace() - 1) / 2
        assert torch.rad2deg(torch.arccos(cosine.clamp(-1, 1))) < 3


def _given_poses(buu, names, path):
    """buu's reference cameras of the photos `names`, written as a transforms.json at `path`."""
    everything = read_transforms_json(buu / "transforms_train.json")
    rows = [everything.names.index(n) if n in everything.names else None for n in names]
    if None in rows:  # the frames' file names as the transforms write them
        stems = [name.rsplit("/", 1)[-1].split(".")[0] for name in everything.names]
        rows = [stems.index(n[:-4]) for n in names]
    given = everything[rows]
    write_transforms_json(path, given)
    return given


def test_given_poses_are_reproduced(run_cli, buu, tmp_path, random_checkpoint):
    photos = _photos(buu, tmp_path)
    given = _given_poses(buu, FRAMES, tmp_path / "poses.json")
    out = tmp_path / "out" / "scene.ply"
    result = run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--poses", tmp_path / "poses.json",
                     "--max-views", 3, "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    assert json.loads(result.out)["geometry"]["source"] == "poses"
    written = read_cameras(out.parent / "cameras.json")
    np.testing.assert_allclose(written.extrinsics.numpy(), given.extrinsics.numpy(), atol=1e-6)
    np.testing.assert_allclose(written.intrinsics.numpy(), given.intrinsics.numpy(), atol=1e-6)
    shutil.copy(buu / "low" / "8.JPG", photos / "8.JPG")
    expect_input_error(run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--poses",
                               tmp_path / "poses.json"), "--poses", "no pose for 1 of 6 photos (8.JPG)")
    (photos / "8.JPG").unlink()
    (photos / "7.JPG").unlink()
    expect_input_error(run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--poses",
                               tmp_path / "poses.json"), "--poses", "1 poses have no photo")


def test_given_poses_without_structure_from_motion_take_the_scale_the_photos_agree_on(run_cli, buu, tmp_path):
    """--poses with --geometry network (or structure-from-motion failing): no sparse points fix the
    depth's scale. The similarity of the bundled model's cameras (nearly one pose) to the given ones
    put the scene ~10x too far, every view a ghosted jumble, exit 0. The oracle: the scene of all 25
    photos registered with structure-from-motion on these poses (`balanced`, 2026-11-27) lies at a
    median 4.85 from the nearest of these 8 cameras (this scene: 4.83; the similarity's: ~50; these
    8 photos' own structure-from-motion, 3 views with points: 8.5)."""
    names = [f"{index}.JPG" for index in range(3, 11)]
    photos = _photos(buu, tmp_path, names)
    given = _given_poses(buu, names, tmp_path / "poses.json")
    # with structure-from-motion (auto), its points reach 3 of the 8 views: the others took the
    # median alignment of those 3 (the scene at 8.5, ghosted doubles); the photos' scale is taken
    for geometry, fitted in (("network", None), ("auto", 3)):
        out = tmp_path / geometry / "scene.ply"
        result = run_cli("restore", photos, "-o", out, "--poses", tmp_path / "poses.json", "--geometry", geometry,
                         "--preset", "fast", "--refine-steps", 0, "--json")
        assert result.code == 0, result.err
        alignment = json.loads(result.out)["geometry"]["depth_alignment"]
        assert alignment["form"] == "photo-consistency scale" and alignment["contrast"] > 0.2, alignment
        assert alignment.get("points_fitted_views") == fitted
        vertices = PlyData.read(str(out))["vertex"]
        means = torch.tensor(np.stack([vertices["x"], vertices["y"], vertices["z"]], axis=1), dtype=torch.float64)
        assert float(torch.cdist(means, given.centers()).min(dim=1).values.median()) == pytest.approx(4.85, rel=0.1)


def test_poses_far_from_their_frames_origin_restore_as_they_do_near_it(run_cli, buu, tmp_path):
    """Georeferenced poses (UTM, ECEF) lie millions of units from their frame's origin, where float32
    rounds a position to half a unit: buu's photos with their poses moved 5e6 out restored as streaks
    (a fortieth of the Gaussians), exit 0. The scene is built centred on the cameras, and summary.json
    says where that centre lies in the poses' frame."""
    photos = _photos(buu, tmp_path)
    given = _given_poses(buu, FRAMES, tmp_path / "near.json")
    shift = torch.tensor([5e6, -3e6, 2e5], dtype=torch.float64)
    far = Cameras(torch.cat([given.extrinsics[:, :, :3], (given.extrinsics[:, :, 3] - given.extrinsics[:, :, :3] @ shift)[:, :, None]], 2),
                  given.intrinsics, given.sizes, given.names)
    write_transforms_json(tmp_path / "far.json", far)
    restored, summaries = {}, {}
    for name in ("near", "far"):
        out = tmp_path / name / "scene.ply"
        result = run_cli("restore", photos, "-o", out, "--poses", tmp_path / f"{name}.json", "--preset", "fast",
                         "--refine-steps", 0, "--json")
        assert result.code == 0, result.err
        summaries[name] = json.loads(result.out)
        restored[name] = [cv2.imread(str(out.parent / "restored" / f"{n[:-4]}.png")).astype(np.float64) for n in FRAMES]
    assert summaries["far"]["gaussians"]["kept"] == pytest.approx(summaries["near"]["gaussians"]["kept"], rel=0.01)
    for near_view, far_view in zip(restored["near"], restored["far"]):
        assert 10 * np.log10(255**2 / np.mean((near_view - far_view) ** 2)) > 35
    assert summaries["near"]["geometry"]["poses_origin"] is None
    origin = torch.tensor(summaries["far"]["geometry"]["poses_origin"], dtype=torch.float64)
    torch.testing.assert_close(origin, far.centers().mean(0), rtol=0, atol=1e-3)  # the file holds 16 digits
    assert "units from the origin" in " ".join(result.err.split())
    written = read_cameras(tmp_path / "far" / "cameras.json")  # the cameras of the centred scene
    torch.testing.assert_close(written.centers().double() + origin, far.centers(), rtol=0, atol=1e-3)


def test_poses_that_do_not_belong_to_the_photos_are_warned_of(run_cli, buu, tmp_path):
    """8 of buu's photos with their poses permuted: a collage of copies, exit 0 and no word; the
    carried points land 269 px from where the given cameras see them (7 px with their own)."""
    names = [f"{index}.JPG" for index in range(3, 11)]
    photos = _photos(buu, tmp_path, names)
    given = _given_poses(buu, names, tmp_path / "right.json")
    order = [3, 0, 6, 1, 7, 2, 5, 4]
    write_transforms_json(tmp_path / "permuted.json", Cameras(given.extrinsics[order], given.intrinsics[order],
                                                              given.sizes, given.names))
    result = run_cli("restore", photos, "-o", tmp_path / "out" / "scene.ply", "--poses", tmp_path / "permuted.json",
                     "--preset", "balanced", "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    said = " ".join(result.err.split())
    assert "structure-from-motion's points land" in said and "the poses do not belong to these photos" in said, said


def test_photos_sfm_cannot_place(run_cli, buu, shared_data, tmp_path, random_checkpoint):
    blank = tmp_path / "blank"
    blank.mkdir()
    for index in range(4):
        cv2.imwrite(str(blank / f"{index}.png"), np.full((120, 160, 3), 40 + index, np.uint8))
    out = tmp_path / "out" / "scene.ply"
    expect_input_error(run_cli("restore", blank, "-o", out, "--checkpoint", random_checkpoint, "--geometry", "sfm"),
                       "--geometry sfm: structure-from-motion registered 0 of 4 photos", "use the network's cameras (--geometry network) or give --poses")
    result = run_cli("restore", blank, "-o", out, "--checkpoint", random_checkpoint, "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    assert json.loads(result.out)["geometry"]["source"] == "network"
    said = " ".join(result.err.split())  # rich wraps long log lines
    assert "registered 0 of 4 photos" in said and "using the network's cameras instead" in said
    one = _photos(buu, tmp_path / "one", ["5.JPG"])
    expect_input_error(run_cli("restore", one, "-o", out, "--checkpoint", random_checkpoint, "--geometry", "sfm"),
                       "--geometry sfm: structure-from-motion needs at least two photos")
    result = run_cli("restore", one, "-o", tmp_path / "one-out" / "scene.ply", "--checkpoint", random_checkpoint,
                     "--refine-steps", 0, "--json")
    assert result.code == 0 and json.loads(result.out)["geometry"]["source"] == "network", result.err
    unrelated = tmp_path / "unrelated"
    unrelated.mkdir()
    for name in ("000.jpg", "010.jpg", "020.jpg", "030.jpg"):
        shutil.copy(shared_data / "lowlight_single" / name, unrelated / name)
    result = run_cli("restore", unrelated, "-o", tmp_path / "u" / "scene.ply", "--checkpoint", random_checkpoint,
                     "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    assert json.loads(result.out)["geometry"]["source"] == "network" and "Traceback" not in result.err


def test_the_depth_sweep_never_compares_with_held_out_views(buu, monkeypatch):
    """Evaluation's holdout leaves the test frames out of the scene: the depth sweep gets the
    other views' photos as neighbours only, the restored photos of the network's views, and its
    depth is what the scene is fused from."""
    from lumos3d_cli.io.images import load_images
    from lumos3d_cli.model.lumos3d import build_model
    from lumos3d_cli.pipeline import scene_geometry
    from lumos3d_cli.pipeline.presets import get_restore_preset
    from lumos3d_cli.pipeline.scene_stages import build_scene

    seen = {}
    real_sweep = scene_geometry.sweep_depth

    def recording_sweep(depth, cameras, images, settings, neighbour_views):
        seen.update(views=list(neighbour_views), images=images.clone())
        result = real_sweep(depth, cameras, images, settings, neighbour_views)
        seen["depth"] = result.depth
        return result

    monkeypatch.setattr(scene_geometry, "sweep_depth", recording_sweep)
    photos = load_images([buu / "low" / name for name in FRAMES]).images
    model = build_model("tiny-operator", seed=0).eval()
    fused = [True, False, False, True, True]
    job = build_scene(photos, FRAMES, model, get_restore_preset("best", refine_steps=0), geometry="sfm",
                      max_views=3, required_views=[2], fuse_views=fused)
    assert job.geometry.source == "sfm" and job.selected == [0, 2, 4]
    assert seen["views"] == [fused[i] for i in job.selected]  # the network's views, in its order
    assert torch.equal(seen["images"], job.restored_photos[job.selected])
    assert torch.equal(seen["depth"], job.geometry.depth)
    assert job.geometry.report["depth_sweep"]["neighbours"] == 4
    seen.clear()
    plain = build_scene(photos, FRAMES, model, get_restore_preset("best", refine_steps=0, depth_sweep=False),
                        geometry="sfm", max_views=3, required_views=[2], fuse_views=fused)
    assert not seen and plain.geometry.report["depth_sweep"] is None


def _dataset_cameras(buu):
    """The dataset's own cameras of FRAMES (buu's transforms_train.json)."""
    everything = read_transforms_json(buu / "transforms_train.json")
    stems = [name.rsplit("/", 1)[-1].split(".")[0] for name in everything.names]
    return everything[[stems.index(n[:-4]) for n in FRAMES]]


def _scaled(extrinsics, scale):
    extrinsics[:, :, 3] *= scale


def _one_far_away(extrinsics, _):
    extrinsics[0, :, 3] = 1e30


@pytest.mark.parametrize("move, amount, refusal", [
    (_scaled, 1e-6, ("no camera sees the scene", "outside the renderer's range")),
    (_scaled, 1e12, ("no camera sees the scene", "outside the renderer's range")),
    # its points lie beyond the voxel grid (an internal error) or every footprint overflows (the
    # refusal named only `gaussians.scales`): the file is named
    (_one_far_away, None, ("poses.json: ", "check the camera file's positions")),
])
def test_camera_files_that_build_no_drawable_scene_are_refused_by_name(run_cli, buu, tmp_path, random_checkpoint,
                                                                        move, amount, refusal):
    """The rasterizer's clipping planes are absolute (0.01 to 1e10 units, as gsplat's): poses in
    extreme units once gave an empty .ply and black views with exit 0."""
    photos = _photos(buu, tmp_path)
    given = _dataset_cameras(buu)
    extrinsics = given.extrinsics.clone()
    move(extrinsics, amount)
    write_transforms_json(tmp_path / "poses.json", Cameras(extrinsics, given.intrinsics, given.sizes, given.names))
    out = tmp_path / "out" / "scene.ply"
    expect_input_error(run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--poses",
                               tmp_path / "poses.json", "--refine-steps", 0), "--poses", *refusal)
    assert not out.parent.exists()


def test_cameras_with_a_field_of_view_no_lens_has(run_cli, buu, tmp_path, random_checkpoint, monkeypatch):
    """Structure-from-motion on few features can settle on focal lengths of tens of thousands of
    pixels (a quarter of a degree): that model counts as failed. Given poses in another unit are
    the user's to judge: a warning, and, where no Gaussian then lands in any view, a refusal."""
    from lumos3d_cli.pipeline import scene_geometry

    real = scene_geometry.register_photos

    def telescopic(*args, **kwargs):
        registration = real(*args, **kwargs)
        registration.cameras.intrinsics[:, :2, :2] *= 200
        return registration

    monkeypatch.setattr(scene_geometry, "register_photos", telescopic)
    photos = _photos(buu, tmp_path)
    out = tmp_path / "out" / "scene.ply"
    expect_input_error(run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--geometry", "sfm"),
                       "--geometry sfm: structure-from-motion gave 5 view(s) a field of view no lens has (3.JPG 0.")
    result = run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    assert json.loads(result.out)["geometry"]["source"] == "network"
    assert "using the network's cameras instead" in " ".join(result.err.split())
    monkeypatch.setattr(scene_geometry, "register_photos", real)
    given = _dataset_cameras(buu)
    for focal, refused in ((1e5, False), (1e30, True)):
        intrinsics = given.intrinsics.clone()
        intrinsics[:, 0, 0] = intrinsics[:, 1, 1] = focal
        write_transforms_json(tmp_path / "poses.json", Cameras(given.extrinsics, intrinsics, given.sizes, given.names))
        result = run_cli("restore", photos, "-o", tmp_path / f"given-{focal:g}" / "scene.ply", "--checkpoint",
                         random_checkpoint, "--poses", tmp_path / "poses.json", "--geometry", "network", "--refine-steps", 0)
        said = " ".join(result.err.split())
        assert "poses.json: 5 view(s) have a field of view no ordinary lens has (3.JPG " in said, said
        if refused:
            expect_input_error(result, "--poses", "no Gaussian of the scene falls inside any camera's view")
        else:
            assert result.code == 0, result.err


def test_one_camera_with_a_field_of_view_no_lens_has_is_placed_like_an_unregistered_view(
        run_cli, buu, tmp_path, random_checkpoint, monkeypatch):
    """One of Strecha's British Museum's 10 photos got a field of view of 0.001 degrees from
    structure-from-motion, which sent all 10 views to the network's cameras (every view a ghosted
    copy). That view alone is placed as one that did not register; the other four keep their
    cameras, and its observations leave the sparse points."""
    from lumos3d_cli.pipeline import scene_geometry

    real = scene_geometry.register_photos

    def one_telescopic(*args, **kwargs):
        registration = real(*args, **kwargs)
        registration.cameras.intrinsics[2, :2, :2] *= 200  # the third photo, 5.JPG
        return registration

    monkeypatch.setattr(scene_geometry, "register_photos", one_telescopic)
    photos = _photos(buu, tmp_path)
    out = tmp_path / "out" / "scene.ply"
    result = run_cli("restore", photos, "-o", out, "--checkpoint", random_checkpoint, "--geometry", "sfm",
                     "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    said = " ".join(result.err.split())
    assert "structure-from-motion gave 1 view(s) a field of view no lens has (5.JPG 0." in said, said
    assert "placed as views it did not register" in said and "not registered by structure-from-motion" in said
    geometry = json.loads(result.out)["geometry"]
    assert geometry["source"] == "sfm" and geometry["registered_views"] == 4
    written = read_colmap_model(out.parent / "colmap")
    points = read_colmap_points(out.parent / "colmap" / "points3D.txt")
    assert written.names == FRAMES and len(points.xyz) == geometry["sparse_points"] > 50
    # the written cameras of the other four are structure-from-motion's (a field of view a lens has)
    assert not scene_geometry.implausible_views(written.intrinsics, written.sizes)


def test_structure_from_motion_far_from_the_networks_focal_length_is_warned_of(run_cli, tmp_path, caplog):
    """Four of the example photos: structure-from-motion on their restoration settles on a focal
    length 2.3x the reference's (843 px against 368; all eight photos: 365) and still reprojects
    its points to 0.3 px, so `auto` keeps it; the bundled network predicts 265: said."""
    from pathlib import Path

    examples = Path(__file__).resolve().parents[2] / "examples" / "lowlight-buu"
    photos = [examples / f"{number}.jpg" for number in (1, 4, 7, 10)]
    result = run_cli("restore", *photos, "-o", tmp_path / "out" / "scene.ply", "--refine-steps", 0)
    assert result.code == 0, result.err
    # (3.2x here; structure-from-motion's exact settling may vary with the machine's threads)
    assert re.search(r"structure-from-motion's focal lengths are [\d.]+x the network's for these photos",
                     result.err + caplog.text)
