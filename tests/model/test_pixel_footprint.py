"""Pixel footprints, the voxel sizes that follow them and the shapes of the voxels they fill,
against values worked out by hand."""

import pytest
import torch

from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.model.geometry import unproject_depth
from lumos3d_cli.model.pixel_footprint import MAX_LEVEL, footprint_voxel_sizes, pixel_footprint
from lumos3d_cli.model.voxelize import covering_shapes, voxelize
from lumos3d_cli.rotations import quaternion_to_matrix

FOCAL = 64.0


def _cameras(views: int, size: int = 8):
    extrinsics = torch.eye(3, 4).expand(views, 3, 4).clone()
    intrinsics = torch.tensor([[FOCAL, 0, size / 2], [0, FOCAL, size / 2], [0, 0, 1]]).expand(views, 3, 3).clone()
    return extrinsics, intrinsics


def test_footprint_is_depth_over_focal_in_the_finest_view_that_holds_the_point():
    extrinsics, intrinsics = _cameras(2)
    extrinsics[1, 2, 3] = 1.5  # the second camera 1.5 further back: z is 1.5 larger there
    intrinsics[1, :2] *= 2.0  # but with twice the focal length (and a centred principal point)
    intrinsics[1, :2, 2] = 4.0
    points = torch.tensor([
        [0.0, 0.0, 1.0],  # both hold it: min(1 / 64, 2.5 / 128) = 1 / 64
        [0.0, 0.0, 4.0],  # both: min(4 / 64, 5.5 / 128) = 5.5 / 128
        [0.0, 0.0, -2.0],  # behind both cameras
        [0.05, 0.0, 1.0],  # u = 64 * 0.05 + 4 = 7.2 in the first; 128 * 0.05 / 2.5 + 4 = 6.56 in the second
        [0.1, 0.0, 1.0],  # u = 10.4 outside the first (8 wide); 128 * 0.1 / 2.5 + 4 = 9.12 outside too
    ])
    footprint = pixel_footprint(points, extrinsics, intrinsics, (8, 8))
    expected = torch.tensor([1 / 64, 5.5 / 128, float("inf"), 1 / 64, float("inf")])
    torch.testing.assert_close(footprint, expected)


def test_voxel_sizes_are_the_largest_power_of_two_of_the_unit_within_the_multiple():
    footprint = torch.tensor([1 / 64, 8 / 64, 3 / 64, 0.0, float("inf"), 1e30])
    sizes = footprint_voxel_sizes(footprint, 2.0, 1.0)
    # 2/64 = 2^-5; 16/64 = 2^-2; 6/64 = 2^-3.415 -> 2^-4; 0 and inf -> the smallest; 1e30 -> the largest
    expected = [2.0**-5, 2.0**-2, 2.0**-4, 2.0**-MAX_LEVEL, 2.0**-MAX_LEVEL, 2.0**MAX_LEVEL]
    assert sizes.tolist() == expected
    assert footprint_voxel_sizes(footprint[:3] * 1000, 2.0, 1000.0).tolist() == expected[:3]  # unit-free
    with pytest.raises(ValueError, match="positive"):
        footprint_voxel_sizes(footprint, 0.0, 1.0)


def test_footprint_voxels_merge_far_pixels_as_much_as_near_ones():
    """Two views through the same 8x8 camera (f = 64): one sees a wall at z = 1, the other at z = 8.
    Neighbouring pixels lie z/64 apart. Voxels of twice the footprint (2^-5 near, 2^-2 far) take
    pixel columns in pairs: along an axis the 8 pixel centres (m + 0.5) footprints from the axis,
    m = -4..3, fall into the cells round((m + 0.5) / 2) = -2, -1, -1, 0, 0, 1, 1, 2: 5 cells, so
    5 x 5 = 25 voxels per wall. One global voxel of 2^-5 (right for the near wall) leaves every far
    pixel alone: 25 + 64."""
    extrinsics, intrinsics = _cameras(2)
    depth = torch.stack([torch.full((8, 8), 1.0), torch.full((8, 8), 8.0)])
    points = unproject_depth(depth, extrinsics, intrinsics)  # [2, 8, 8, 3]
    footprint = pixel_footprint(points.reshape(-1, 3), extrinsics, intrinsics, (8, 8))
    torch.testing.assert_close(footprint, (depth / FOCAL).reshape(-1))
    sizes = footprint_voxel_sizes(footprint, 2.0, 1.0)
    features, confidence = torch.zeros(128, 1), torch.zeros(128)
    adaptive = voxelize(points.reshape(-1, 3), features, confidence, sizes)
    fixed = voxelize(points.reshape(-1, 3), features, confidence, 2.0**-5)
    near = adaptive.inverse[:64].unique().numel()
    far = adaptive.inverse[64:].unique().numel()
    assert (near, far) == (25, 25) and len(adaptive) == 50
    assert fixed.inverse[:64].unique().numel() == 25 and fixed.inverse[64:].unique().numel() == 64


def test_points_of_different_sizes_never_share_a_voxel():
    points = torch.zeros(4, 3)
    sizes = torch.tensor([1.0, 1.0, 0.5, 2.0])
    fused = voxelize(points, torch.arange(4.0)[:, None], torch.zeros(4), sizes)
    assert len(fused) == 3 and fused.counts.tolist() == [1, 2, 1]  # ordered by size: 0.5, 1, 2
    torch.testing.assert_close(fused.features[:, 0], torch.tensor([2.0, 0.5, 3.0]))
    with pytest.raises(ValueError, match="3 voxel sizes for 4 points"):
        voxelize(points, torch.zeros(4, 1), torch.zeros(4), sizes[:3])


def test_empty_and_extreme_inputs_stay_finite():
    extrinsics, intrinsics = _cameras(1)
    assert pixel_footprint(torch.zeros(0, 3), extrinsics, intrinsics, (8, 8)).shape == (0,)
    for scale in (1e-6, 1e3):
        points = torch.tensor([[0.0, 0.0, 1.0], [0.01, 0.0, 1.0]]) * scale
        sizes = footprint_voxel_sizes(pixel_footprint(points, extrinsics, intrinsics, (8, 8)), 1.0, torch.tensor(scale))
        assert torch.isfinite(sizes).all() and (sizes > 0).all()
        fused = voxelize(points, torch.zeros(2, 1), torch.zeros(2), sizes * scale)
        assert torch.isfinite(fused.points).all()


def test_covering_shapes_span_the_members_by_hand():
    """Two isotropic members (s = 0.1) at x = -0.3 and +0.3 with equal weights fuse at x = 0 with
    covariance diag(0.1^2 + 0.3^2, 0.1^2, 0.1^2); a lone third member keeps its own shape."""
    quats = torch.tensor([[1.0, 0, 0, 0], [1.0, 0, 0, 0], [0.6, 0.8, 0, 0]])
    members = Gaussians(torch.tensor([[-0.3, 0, 0], [0.3, 0, 0], [5.0, 0, 0]]), quats,
                        torch.tensor([[0.1] * 3, [0.1] * 3, [0.2, 0.3, 0.4]]), torch.ones(3), torch.zeros(3, 1, 3))
    fused = voxelize(members.means, torch.zeros(3, 1), torch.zeros(3), torch.tensor([1.0, 1.0, 1.0]))
    mean_shapes = Gaussians(fused.points, torch.tensor([[1.0, 0, 0, 0], [0.6, 0.8, 0, 0]]),
                            torch.tensor([[0.1] * 3, [0.2, 0.3, 0.4]]), torch.ones(2), torch.zeros(2, 1, 3))
    covered = covering_shapes(mean_shapes, members, fused, min_scale=1e-7)
    rotation = quaternion_to_matrix(covered.quats[0])
    covariance = rotation @ torch.diag(covered.scales[0] ** 2) @ rotation.T
    torch.testing.assert_close(covariance, torch.diag(torch.tensor([0.1, 0.01, 0.01])))
    assert torch.equal(covered.quats[1], mean_shapes.quats[1]) and torch.equal(covered.scales[1], mean_shapes.scales[1])
    torch.testing.assert_close(covered.means, torch.tensor([[0.0, 0, 0], [5.0, 0, 0]]))


def test_covering_shapes_of_coincident_flat_members_stay_positive():
    members = Gaussians(torch.zeros(2, 3), torch.tensor([[1.0, 0, 0, 0]] * 2), torch.tensor([[0.1, 0.1, 0.0]] * 2),
                        torch.ones(2), torch.zeros(2, 1, 3))
    fused = voxelize(members.means, torch.zeros(2, 1), torch.zeros(2), 1.0)
    covered = covering_shapes(members.select(torch.tensor([0])), members, fused, min_scale=1e-4)
    assert covered.scales.min() == pytest.approx(1e-4) and torch.isfinite(covered.quats).all()
