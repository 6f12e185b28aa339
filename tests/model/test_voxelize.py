import math

import pytest
import torch

from lumos3d_cli.errors import NonFiniteError
from lumos3d_cli.model.geometry import unproject_depth
from lumos3d_cli.model.voxelize import _cell_keys, voxel_cells, voxelize


def test_fusion_by_hand():
    # voxel 0.1: points 0 and 1 share cell (0,0,0); point 2 is alone in cell (10,0,0)
    points = torch.tensor([[0.0, 0.0, 0.0], [0.04, 0.0, 0.0], [1.0, 0.0, 0.0]])
    features = torch.tensor([[1.0, 10.0], [5.0, 20.0], [7.0, 7.0]])
    confidence = torch.tensor([0.0, math.log(3.0), -50.0])  # softmax weights 1/4, 3/4 in the shared voxel
    fused = voxelize(points, features, confidence, 0.1)
    assert len(fused) == 2 and fused.counts.tolist() == [2, 1]
    torch.testing.assert_close(fused.weights, torch.tensor([0.25, 0.75, 1.0]))
    torch.testing.assert_close(fused.points, torch.tensor([[0.03, 0.0, 0.0], [1.0, 0.0, 0.0]]))
    torch.testing.assert_close(fused.features, torch.tensor([[4.0, 17.5], [7.0, 7.0]]))
    assert fused.inverse.tolist() == [0, 0, 1]


def test_cells_round_to_nearest_not_floor():
    cells = voxel_cells(torch.tensor([[0.14, -0.14, 0.26]]), 0.1)
    assert cells.tolist() == [[1, -1, 3]]


def test_softmax_is_stable_for_huge_confidences():
    points = torch.zeros(3, 3)
    fused = voxelize(points, torch.tensor([[1.0], [2.0], [3.0]]), torch.tensor([1e4, 1e4, -1e4]), 1.0)
    torch.testing.assert_close(fused.features, torch.tensor([[1.5]]))


def test_gradients_reach_every_pixel_gaussian():
    generator = torch.Generator().manual_seed(0)
    points = (torch.rand(500, 3, generator=generator) * 2).requires_grad_()
    features = torch.randn(500, 6, generator=generator).requires_grad_()
    confidence = torch.randn(500, generator=generator).requires_grad_()
    fused = voxelize(points, features, confidence, 0.3)
    assert len(fused) < 500  # some voxels hold several points
    target = torch.randn(fused.features.shape, generator=generator)
    ((fused.features * target).sum() + fused.points.square().sum()).backward()
    assert (features.grad.abs().sum(dim=1) > 0).all()
    assert (points.grad.abs().sum(dim=1) > 0).all()
    shared = fused.counts[fused.inverse] > 1
    assert (confidence.grad[shared] != 0).all()
    assert (confidence.grad[~shared] == 0).all()  # a lone member always has weight 1


def test_two_identical_views_of_a_plane_fuse_to_one_views_worth():
    height, width = 60, 80
    extrinsics = torch.eye(3, 4).expand(2, 3, 4)
    intrinsics = torch.tensor([[80.0, 0, 40], [0, 80, 30], [0, 0, 1]]).expand(2, 3, 3)
    depth = torch.full((2, height, width), 3.0)  # fronto-parallel plane at z = 3
    points = unproject_depth(depth, extrinsics, intrinsics).reshape(-1, 3)
    features = torch.randn(height * width, 4).repeat(2, 1)  # both views see the same colours
    footprint = 3.0 / 80.0  # distance between neighbouring pixels on the plane
    one_view = height * width
    for voxel_size in (0.5 * footprint, 0.9 * footprint):
        fused = voxelize(points, features, torch.randn(points.shape[0]), voxel_size)
        assert len(fused) == one_view and (fused.counts == 2).all()
        torch.testing.assert_close(fused.features, features[:one_view][torch.argsort(fused.inverse[:one_view])])
    # the second view's depth off by a little noise (2% of a pixel footprint): still about one view
    jittered = depth.clone()
    jittered[1] += 0.02 * footprint * torch.randn(height, width, generator=torch.Generator().manual_seed(3))
    points = unproject_depth(jittered, extrinsics, intrinsics).reshape(-1, 3)
    fused = voxelize(points, features, torch.zeros(points.shape[0]), 0.5 * footprint)
    assert one_view <= len(fused) <= 1.1 * one_view


def test_scaling_the_scene_and_the_voxel_together_changes_nothing_but_units():
    generator = torch.Generator().manual_seed(1)
    points = torch.rand(300, 3, generator=generator, dtype=torch.float64)
    features = torch.randn(300, 2, generator=generator, dtype=torch.float64)
    confidence = torch.randn(300, generator=generator, dtype=torch.float64)
    base = voxelize(points, features, confidence, 0.125)
    scaled = voxelize(points * 1024.0, features, confidence, 0.125 * 1024.0)
    assert torch.equal(base.inverse, scaled.inverse)
    torch.testing.assert_close(scaled.points, base.points * 1024.0)
    torch.testing.assert_close(scaled.features, base.features)


def test_cell_keys_identify_cells_also_when_coordinates_spread_too_far_to_pack():
    generator = torch.Generator().manual_seed(2)
    near = torch.randint(-5, 5, (2000, 3), generator=generator)
    far = near * (1 << 40)  # extents ~2^43 per axis: the packed key would overflow int64
    for cells in (near, far):
        keys = _cell_keys(cells)
        _, expected = torch.unique(cells, dim=0, return_inverse=True)
        _, actual = torch.unique(keys, return_inverse=True)
        assert torch.equal(actual, expected)  # same partition and the same (lexicographic) order


def test_non_finite_points_are_refused():
    points = torch.tensor([[0.0, 0.0, float("nan")]])
    with pytest.raises(NonFiniteError):
        voxelize(points, torch.zeros(1, 1), torch.zeros(1), 0.1)


@pytest.mark.parametrize("size", [0.0, -0.1, float("nan"), float("inf"), torch.tensor([0.1, 0.0, 0.1])])
def test_voxel_sizes_that_are_not_positive_and_finite_are_refused(size):
    """A size of 0 or NaN fused three distinct points into one voxel; a negative one was used."""
    points = torch.tensor([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    with pytest.raises(ValueError, match="voxel size .*: must be positive and finite"):
        voxelize(points, torch.zeros(3, 1), torch.zeros(3), size)


def test_cells_beyond_int64_are_refused_not_wrapped_into_one():
    """Points at +-1e17 with voxels of 0.01 (1e19 cells) wrapped in .long(): +1e17 fell into the
    voxel of -1e17 and the two fused at the origin; a voxel of 1e-30 merged points 1 and 2."""
    far = torch.tensor([[1e17, 0, 0], [-1e17, 0, 0], [5, 0, 0]])
    with pytest.raises(ValueError, match="beyond 2\\^61 voxels"):
        voxelize(far, torch.zeros(3, 1), torch.zeros(3), 0.01)
    with pytest.raises(ValueError, match="beyond 2\\^61 voxels"):
        voxel_cells(torch.tensor([[0.0, 0, 0], [1, 0, 0]]), 1e-30)
    assert len(voxelize(far, torch.zeros(3, 1), torch.zeros(3), 1e3)) == 3
