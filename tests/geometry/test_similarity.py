import math

import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.similarity import (
    Similarity, fill_unregistered_views, fit_camera_similarity, fit_similarity, transform_cameras,
)
from lumos3d_cli.rotations import quaternion_to_matrix

from synthetic_scene import plane_cameras


def _known_similarity() -> Similarity:
    rotation = quaternion_to_matrix(torch.tensor([0.8, 0.2, -0.5, 0.26], dtype=torch.float64))
    return Similarity(2.7, rotation, torch.tensor([1.0, -4.0, 0.5], dtype=torch.float64))


def test_fit_recovers_a_known_similarity():
    known = _known_similarity()
    source = torch.randn(50, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    fitted = fit_similarity(source, known.apply(source))
    assert fitted.scale == pytest.approx(known.scale, rel=1e-12)
    torch.testing.assert_close(fitted.rotation, known.rotation, atol=1e-12, rtol=0)
    torch.testing.assert_close(fitted.translation, known.translation, atol=1e-12, rtol=0)
    torch.testing.assert_close(fitted.inverse().apply(known.apply(source)), source, atol=1e-12, rtol=0)


def test_fit_with_three_points_and_noise():
    known = _known_similarity()
    source = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=torch.float64)
    assert fit_similarity(source, known.apply(source)).scale == pytest.approx(known.scale, rel=1e-12)
    many = torch.randn(400, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    noisy = known.apply(many) + 0.01 * torch.randn(400, 3, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    assert fit_similarity(many, noisy).scale == pytest.approx(known.scale, rel=1e-3)


@pytest.mark.parametrize("points", [
    torch.zeros(2, 3, dtype=torch.float64),  # too few
    torch.tensor([[0.0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]], dtype=torch.float64),  # one line
    torch.ones(5, 3, dtype=torch.float64),  # one point
    torch.tensor([[0.0, 0, 0], [1, 0, 0], [float("nan"), 1, 0]], dtype=torch.float64),
])
def test_fit_refuses_degenerate_points(points):
    with pytest.raises(InputError):
        fit_similarity(points, points)


def test_transformed_cameras_see_the_transformed_points_at_the_same_pixels():
    cameras = plane_cameras(5)
    known = _known_similarity()
    points = torch.randn(30, 3, generator=torch.Generator().manual_seed(3), dtype=torch.float64) + torch.tensor([0, 0, 6.0], dtype=torch.float64)
    pixels, depth = cameras.project(points)
    moved = transform_cameras(cameras, known)
    moved.require_valid()
    moved_pixels, moved_depth = moved.project(known.apply(points))
    torch.testing.assert_close(moved_pixels, pixels, atol=1e-9, rtol=0)
    torch.testing.assert_close(moved_depth, known.scale * depth, atol=1e-9, rtol=0)


def test_camera_similarity_from_two_cameras_and_from_collinear_centres():
    cameras = plane_cameras(6)
    known = _known_similarity()
    moved = transform_cameras(cameras, known)
    for subset in ([0, 5], [0, 1, 2, 3, 4, 5]):
        fitted = fit_camera_similarity(cameras[subset], moved[subset])
        assert fitted.scale == pytest.approx(known.scale, rel=1e-9)
        torch.testing.assert_close(fitted.rotation, known.rotation, atol=1e-9, rtol=0)
    collinear = plane_cameras(4)
    collinear.extrinsics[:, :, 3] = -(collinear.extrinsics[:, :, :3] @ torch.tensor(
        [[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], dtype=torch.float64)[:, :, None])[..., 0]
    fitted = fit_camera_similarity(collinear, transform_cameras(collinear, known))
    torch.testing.assert_close(fitted.rotation, known.rotation, atol=1e-9, rtol=0)
    with pytest.raises(InputError):
        fit_camera_similarity(cameras[[0]], moved[[0]])


def test_fill_unregistered_views_places_the_others_by_the_registered_ones():
    truth = plane_cameras(7)
    known = _known_similarity()
    network = transform_cameras(truth, known.inverse())  # the same cameras in another frame
    network.intrinsics[:, 0, 0] *= 1.1  # a network's focal guess, replaced by the shared camera
    registered = torch.tensor([True, True, False, True, True, False, True])
    filled = fill_unregistered_views(truth[registered.nonzero().flatten().tolist()], registered, network)
    torch.testing.assert_close(filled.extrinsics, truth.extrinsics, atol=1e-9, rtol=0)
    torch.testing.assert_close(filled.intrinsics, truth.intrinsics, atol=1e-12, rtol=0)
    assert filled.names == network.names
    with pytest.raises(InputError):
        fill_unregistered_views(truth[[0, 1]], registered, network)
    assert math.isfinite(float(filled.extrinsics.sum()))
