"""Structure-from-motion against independent ground truth: the Strecha scenes' benchmark cameras
and LOM buu's dataset cameras. The fast tests use a few small photos; the full scenes are slow."""

from pathlib import Path

import pycolmap
import pytest
import torch
import torch.nn.functional as F

from lumos3d_cli.data.degradations import Degradation, apply_degradation, sample_parameters
from lumos3d_cli.data.lom import lom_reference_extrinsics, read_lom_scene
from lumos3d_cli.errors import InputError
from lumos3d_cli.eval.metrics import auto_gamma
from lumos3d_cli.eval.pose_accuracy import pose_accuracy
from lumos3d_cli.geometry.sfm import Registration, register_photos
from lumos3d_cli.io.colmap import read_colmap_model
from lumos3d_cli.io.images import load_images


@pytest.fixture(scope="module")
def buu_low(buu):
    """buu's low-light photos brightened by the blind curve, their names and reference extrinsics."""
    scene = read_lom_scene(buu, "low-light")
    batch = load_images([scene.degraded[frame] for frame in scene.frames])
    reference = lom_reference_extrinsics(scene)
    return auto_gamma(batch.images), [p.name for p in batch.paths], torch.stack([reference[f] for f in scene.frames])


def _strecha(shared_data: Path, name: str):
    """Photos [V, 3, H, W] and ground-truth cameras in the photos' order."""
    root = shared_data / "gt_cameras" / name
    batch = load_images(root / "images")
    truth = read_colmap_model(root / "sparse" / "0")
    row = {n: i for i, n in enumerate(truth.names)}
    return batch.images, [p.name for p in batch.paths], truth[[row[p.name] for p in batch.paths]]


def _darkened_as_the_cli_does(images: torch.Tensor) -> torch.Tensor:
    """`lumos3d degrade --mode low-light --noise --seed 0` (shared parameters, 8-bit PNGs)."""
    degradation = Degradation("low-light", noise=True)
    generator = torch.Generator().manual_seed(0)
    parameters = sample_parameters(degradation, (), generator)
    dark = torch.stack([apply_degradation(image, "low-light", parameters, generator) for image in images])
    return (dark * 255).round() / 255


def _registered_extrinsics(registration: Registration, reference: torch.Tensor):
    rows = registration.registered_indices
    return registration.cameras.extrinsics, reference[rows]


def _assert_observations_reproject(registration: Registration, pixels_tolerance: float):
    """The returned cameras, points and observations agree in the photos' pixels."""
    row_of_view = {view: row for row, view in enumerate(registration.registered_indices)}
    rows = torch.tensor([row_of_view[int(v)] for v in registration.points.view])
    projected, depth = registration.cameras.project(registration.points.xyz)
    assert (depth[rows, registration.points.point] > 0).all()
    error = (projected[rows, registration.points.point] - registration.points.pixel).norm(dim=1)
    assert float(error.mean()) < pixels_tolerance
    assert registration.reprojection_error < pixels_tolerance
    # the reported figure is the mean over the observations, as this reprojection measures it
    # (pycolmap's own mean is over the points: 0.551 against 0.536 on buu's over-exposed photos)
    assert registration.reprojection_error == pytest.approx(float(error.mean()), rel=1e-9)


def test_a_few_small_photos_register(buu_low):
    images, names, reference = buu_low
    views = [0, 1, 2, 3, 4, 5]
    # One thread: COLMAP is deterministic then; with few photos its focal length can settle in a
    # wrong minimum on some multi-threaded runs (spaced-out subsets of buu did, 25 views never).
    registration = register_photos(images[views], [names[i] for i in views], long_side=256, threads=1)
    assert registration.registered.all() and registration.looks_like_one_scene and not registration.failed
    assert registration.cameras.sizes == [(500, 375)] * 6  # at the photos' resolution, not SfM's
    assert registration.sfm_size == (256, 192)
    assert registration.cameras.names == [names[i] for i in views]
    accuracy = pose_accuracy(*_registered_extrinsics(registration, reference[views]))
    assert accuracy.rotation_error_median < 2.0
    assert float(registration.cameras.intrinsics[0, 0, 0]) == pytest.approx(735.4, rel=0.05)  # transforms' fl_x
    _assert_observations_reproject(registration, 2.0)
    assert len(registration.points) > 100 and torch.bincount(registration.points.point).min() >= 2
    assert registration.seconds > 0 and set(registration.stage_seconds) == {"features", "matching", "mapping"}


def test_photos_of_two_scenes_are_flagged(buu_low, shared_data):
    images, _, _ = buu_low
    fountain, _, _ = _strecha(shared_data, "fountain-P11")
    fountain = F.interpolate(fountain[:4], size=images.shape[-2:], mode="bilinear", antialias=True)
    registration = register_photos(torch.cat([images[[0, 3, 6, 9]], fountain]), [f"{i}.png" for i in range(8)], long_side=320, threads=1)
    assert not registration.looks_like_one_scene
    assert registration.registered_count <= 4 and "overlap too little to join, or show more than one scene" in registration.describe()


@pytest.mark.parametrize("photos", [
    torch.full((4, 3, 120, 160), 0.5),  # blank
    torch.rand(4, 3, 120, 160, generator=torch.Generator().manual_seed(0)),  # unrelated noise
])
def test_textureless_or_unrelated_photos_fail_without_an_exception(photos):
    registration = register_photos(photos, [f"{i}.png" for i in range(4)])
    assert registration.failed and registration.registered_count == 0
    assert len(registration.cameras) == 0 and len(registration.points) == 0
    assert "no model" in registration.describe()


def test_two_photos_register(buu_low):
    images, names, reference = buu_low
    registration = register_photos(images[[0, 2]], [names[0], names[2]], threads=1)
    assert registration.registered_count == 2 and len(registration.cameras) == 2
    assert pose_accuracy(registration.cameras.extrinsics, reference[[0, 2]]).rotation_error_median < 3.0
    _assert_observations_reproject(registration, 2.0)


def test_bad_input_is_an_input_error():
    with pytest.raises(InputError, match="at least 2 photos"):
        register_photos(torch.rand(1, 3, 32, 32), ["a.png"])
    with pytest.raises(InputError, match="names"):
        register_photos(torch.rand(3, 3, 32, 32), ["a.png"])
    with pytest.raises(InputError):
        register_photos(torch.rand(3, 32, 32), ["a.png"] * 3)
    nan = torch.rand(2, 3, 32, 32)
    nan[0, 0, 0, 0] = float("nan")
    with pytest.raises(InputError):
        register_photos(nan, ["a.png", "b.png"])


@pytest.mark.slow
@pytest.mark.parametrize("darkened", [False, True], ids=["as-given", "darkened-and-brightened"])
def test_fountain_registers_every_view_within_a_degree(shared_data, darkened):
    images, names, truth = _strecha(shared_data, "fountain-P11")
    if darkened:
        images = auto_gamma(_darkened_as_the_cli_does(images))
    registration = register_photos(images, names)
    assert registration.registered.all() and registration.looks_like_one_scene
    accuracy = pose_accuracy(registration.cameras.extrinsics, truth.extrinsics)
    assert accuracy.rotation_error_median <= 1.0
    focal = registration.cameras.intrinsics[:, 0, 0]
    assert torch.allclose(focal, truth.intrinsics[:, 0, 0], rtol=0.03)
    _assert_observations_reproject(registration, 1.5)


@pytest.mark.slow
def test_buu_low_light_registers_all_views(buu_low):
    images, names, reference = buu_low
    registration = register_photos(images, names)
    assert registration.registered.all() and registration.matching == "exhaustive"
    accuracy = pose_accuracy(registration.cameras.extrinsics, reference)
    assert accuracy.auc_30 >= 0.85 and accuracy.rotation_error_median < 1.0
    _assert_observations_reproject(registration, 1.5)


@pytest.mark.slow
def test_sequential_matching_registers_an_ordered_capture(shared_data):
    images, names, truth = _strecha(shared_data, "castle-P30")
    registration = register_photos(images, names, exhaustive_limit=10)
    # benchmarks/sfm.py saw 29 or 30 of 30 (multi-threaded COLMAP is not reproducible)
    assert registration.matching == "sequential" and registration.registered_count >= 28
    reference = truth.extrinsics[registration.registered_indices]
    assert pose_accuracy(registration.cameras.extrinsics, reference).rotation_error_median <= 1.0


def test_the_ransac_floor_is_lowered_only_for_many_photos():
    """Many photos (buu's 25, above: every view within a degree) verify with the lower floor; a
    few keep COLMAP's, which held the focal length of a one-photo camera (tests/cli/test_faults.py)."""
    from lumos3d_cli.geometry.colmap_run import VERIFICATION_FLOOR_FROM_VIEWS, VERIFICATION_MIN_TRIALS, _options

    default = pycolmap.TwoViewGeometryOptions().ransac.min_num_trials
    few = _options(1, 4096, VERIFICATION_FLOOR_FROM_VIEWS - 1, 1)[3]
    many = _options(1, 4096, VERIFICATION_FLOOR_FROM_VIEWS, 1)[3]
    assert few.ransac.min_num_trials == default == 100
    assert many.ransac.min_num_trials == VERIFICATION_MIN_TRIALS < default


def test_colmap_logging_is_put_back_when_runs_in_two_threads_overlap():
    """Each run saved the process's level and put back what it found: B, entering while A had
    turned logging off, put "off" back after A had restored it, for good."""
    from lumos3d_cli.geometry.colmap_run import quiet_colmap

    before = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 1  # the user's
    try:
        first, second = quiet_colmap(), quiet_colmap()
        first.__enter__()
        second.__enter__()
        assert pycolmap.logging.minloglevel == 3
        first.__exit__(None, None, None)
        assert pycolmap.logging.minloglevel == 3  # the other run still inside
        second.__exit__(None, None, None)
        assert pycolmap.logging.minloglevel == 1
    finally:
        pycolmap.logging.minloglevel = before


def test_a_view_taken_out_of_a_registration_takes_its_observations_and_lone_points_along():
    """Registration.without_views: the view's camera and observations go, points only it observed
    go, and every other observation still names its own point and view."""
    from lumos3d_cli.io.sparse_points import SparsePoints
    from synthetic_scene import plane_cameras

    cameras = plane_cameras(3)  # photos 0, 2 and 3 of four registered
    xyz = torch.tensor([[0.0, 0.0, 5.0], [1.0, 0.0, 5.0], [0.0, 1.0, 6.0]], dtype=torch.float64)
    view = torch.tensor([0, 2, 2, 3, 0, 3])
    point = torch.tensor([0, 0, 1, 1, 2, 2])
    # observed 0.5 px from where the cameras project them, but photo 2's 5 px (a camera gone wrong)
    row = torch.tensor([0, -1, 1, 2])[view]
    projected = torch.stack([cameras[[int(r)]].project(xyz[[int(p)]])[0][0, 0] for r, p in zip(row, point)])
    offset = torch.where((view == 2)[:, None], torch.tensor([3.0, 4.0]), torch.tensor([0.3, 0.4])).double()
    points = SparsePoints(xyz, torch.tensor([[1, 1, 1], [2, 2, 2], [3, 3, 3]], dtype=torch.uint8),
                          torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64), view, point, projected + offset)
    registration = Registration(cameras, torch.tensor([True, False, True, True]), points, 2.0, [3, 1], "exhaustive",
                                [(48, 32)] * 4, 1.0)
    both = registration.without_views([2, 3])
    assert both.registered.tolist() == [True, False, False, False] and both.cameras.names == [cameras.names[0]]
    assert both.points.view.tolist() == [0, 0] and both.points.point.tolist() == [0, 1]  # point 1: photos 2, 3 alone
    torch.testing.assert_close(both.points.pixel, points.pixel[[0, 4]])
    assert both.points.rgb.tolist() == [[1, 1, 1], [3, 3, 3]]
    one = registration.without_views([2])
    assert one.registered_indices == [0, 3] and one.cameras.names == [cameras.names[0], cameras.names[2]]
    assert len(one.points) == 3 and one.points.view.tolist() == [0, 3, 0, 3]
    # the errors measured again without the dropped camera's observations; its model one view smaller
    torch.testing.assert_close(one.points.error, torch.full((3,), 0.5, dtype=torch.float64))
    assert one.reprojection_error == pytest.approx(0.5) and one.model_sizes == [2, 1]
    # the frame normalised again as COLMAP does (the remaining centres' 10-90 % box 10 units
    # across, centred), one similarity: every point projects where it did in every kept camera
    centres = one.cameras.centers()
    low, high = torch.quantile(centres, 0.1, dim=0), torch.quantile(centres, 0.9, dim=0)
    assert float((high - low).norm()) == pytest.approx(10.0) and float(((high + low) / 2).norm()) < 1e-9
    before, _ = cameras[[0, 2]].project(xyz)
    after, _ = one.cameras.project(one.points.xyz)
    torch.testing.assert_close(after, before, rtol=0, atol=1e-9)
    assert registration.without_views([1]) is registration  # not registered: nothing to take out
