import math

import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.depth_alignment import DEPTH_FORMS, align_depth, fit_scale_shift, sample_depth
from lumos3d_cli.model.geometry import unproject_depth
from lumos3d_cli.io.sparse_points import SparsePoints

from synthetic_scene import plane_cameras, plane_depth, plane_points


def _network_depth(true_depth: torch.Tensor, scale: float, shift: float, form: str) -> torch.Tensor:
    """The depth a network would predict if the true depth is its affine image in `form`."""
    if form == "depth":
        return (true_depth - shift) / scale
    return scale / (1.0 / true_depth - shift)


def _with_outliers(points: SparsePoints, share: float, seed: int = 0) -> SparsePoints:
    """Move a share of the points far off the plane (wrong matches)."""
    generator = torch.Generator().manual_seed(seed)
    wrong = torch.rand(len(points), generator=generator) < share
    xyz = points.xyz.clone()
    xyz[wrong] *= 0.5 + torch.rand(int(wrong.sum()), 1, generator=generator, dtype=torch.float64)
    return SparsePoints(xyz, points.rgb, points.error, points.view, points.point, points.pixel)


@pytest.mark.parametrize("form", DEPTH_FORMS)
def test_alignment_recovers_a_known_scale_and_shift_despite_outliers(form):
    cameras = plane_cameras(4)
    truth = plane_depth(cameras)
    scale, shift = (2.5, 0.8) if form == "depth" else (0.4, 0.05)
    network = _network_depth(truth, scale, shift, form)
    points = _with_outliers(plane_points(cameras, 300), share=0.2)
    result = align_depth(network, cameras, points, form=form)
    assert result.fitted.all() and result.form == form
    torch.testing.assert_close(result.scale, torch.full((4,), scale, dtype=torch.float64), rtol=1e-3, atol=0)
    torch.testing.assert_close(result.shift, torch.full((4,), shift, dtype=torch.float64), rtol=0, atol=2e-3 * scale)
    assert float(((result.depth - truth).abs() / truth).max()) < 1e-3
    assert result.median_residual() < 1e-3  # the median ignores the 20 % of wrong points


def test_views_without_points_take_the_median_alignment():
    cameras = plane_cameras(5)
    truth = plane_depth(cameras)
    network = _network_depth(truth, 2.0, 0.0, "depth")
    points = plane_points(cameras, 200)
    keep = points.view != 2
    sparse = SparsePoints(points.xyz, points.rgb, points.error, points.view[keep], points.point[keep], points.pixel[keep])
    result = align_depth(network, cameras, sparse, form="depth")
    assert result.fitted.tolist() == [True, True, False, True, True]
    assert result.points[2] == 0 and math.isnan(float(result.residual[2]))
    assert float(result.scale[2]) == pytest.approx(2.0, rel=1e-4)  # bilinear samples of 1/linear depth
    assert float(((result.depth[2] - truth[2]).abs() / truth[2]).max()) < 1e-4


def test_alignment_without_enough_points_anywhere_is_an_input_error():
    cameras = plane_cameras(3)
    network = plane_depth(cameras)
    with pytest.raises(InputError, match="sparse points"):
        align_depth(network, cameras, plane_points(cameras, 5), min_points=16)
    with pytest.raises(InputError):
        align_depth(network, cameras, SparsePoints.empty())


def test_non_finite_or_misshapen_depth_is_refused():
    cameras = plane_cameras(3)
    depth = plane_depth(cameras)
    depth[1, 3, 4] = float("nan")
    with pytest.raises(InputError):
        align_depth(depth, cameras, plane_points(cameras, 100))
    with pytest.raises(InputError):
        align_depth(depth[:2], cameras, plane_points(cameras, 100))
    with pytest.raises(InputError, match="form"):
        align_depth(plane_depth(cameras), cameras, plane_points(cameras, 100), form="disparity")


def test_aligned_depth_stays_positive_and_finite_when_the_fit_crosses_zero():
    cameras = plane_cameras(2)
    truth = plane_depth(cameras)
    points = plane_points(cameras, 200)
    # A network depth that is flat where the truth is not makes the fitted map negative at one end.
    network = truth.clone()
    network[:, :, :8] = truth[:, :, :8].mean()
    for form in DEPTH_FORMS:
        result = align_depth(network, cameras, points, form=form)
        assert torch.isfinite(result.depth).all() and (result.depth > 0).all()


@pytest.mark.parametrize("form", DEPTH_FORMS)
def test_depth_that_runs_against_the_points_gets_a_positive_scale_only(form):
    # The bundled tiny model's near-flat depth on riverview anti-correlates with SfM's points: the
    # affine fit's scale is negative in every view, which used to leave every view unaligned.
    cameras = plane_cameras(3)
    truth = plane_depth(cameras)
    inverted = 2 * truth.mean() - truth  # nearest where the truth is farthest
    result = align_depth(inverted, cameras, plane_points(cameras, 200), form=form)
    assert result.fitted.all() and result.scale_only.all() and (result.scale > 0).all()
    assert (result.shift == 0).all()
    assert torch.isfinite(result.depth).all() and (result.depth > 0).all()
    # The size is right: the aligned median depth matches the truth's within the spread of the truth.
    ratio = float(result.depth.median() / truth.median())
    assert 0.7 < ratio < 1.4
    honest = align_depth(truth, cameras, plane_points(cameras, 200), form=form)
    assert not honest.scale_only.any()


def test_constant_network_depth_fits_a_scale_only():
    source = torch.full((50,), 3.0, dtype=torch.float64)
    target = torch.full((50,), 6.0, dtype=torch.float64)
    scale, shift = fit_scale_shift(source, target)
    assert scale == pytest.approx(2.0) and shift == 0.0


def test_sampling_is_bilinear_at_pixel_centres_and_nan_outside():
    depth = torch.arange(12, dtype=torch.float64).reshape(3, 4)
    pixels = torch.tensor([[0.5, 0.5], [1.0, 0.5], [3.5, 2.5], [-1.0, 1.0], [2.0, 9.0]], dtype=torch.float64)
    values = sample_depth(depth, pixels)
    torch.testing.assert_close(values[:3], torch.tensor([0.0, 0.5, 11.0], dtype=torch.float64))
    assert torch.isnan(values[3:]).all()


def test_unprojected_aligned_depth_lies_on_the_plane():
    from synthetic_scene import PLANE_NORMAL, PLANE_OFFSET

    cameras = plane_cameras(3)
    depth = plane_depth(cameras)
    world = unproject_depth(depth, cameras.extrinsics.to(depth.dtype), cameras.intrinsics.to(depth.dtype))
    torch.testing.assert_close(world @ PLANE_NORMAL, torch.full(world.shape[:-1], PLANE_OFFSET, dtype=torch.float64))
