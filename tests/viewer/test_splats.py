import math

import numpy as np
import pytest
import torch

from lumos3d_cli.io.cameras import Cameras, make_intrinsics
from lumos3d_cli.viewer.framing import VIEWER_RADIUS, camera_up, frame_scene
from lumos3d_cli.viewer.splats import covariances, select_splats, splat_arrays

from factories import random_gaussians


def test_covariance_is_rotation_times_squared_scales():
    half = math.sqrt(0.5)
    # 90 degrees about z (wxyz): the local x axis becomes world y.
    sigma = covariances(torch.tensor([[half, 0.0, 0.0, half]]), torch.tensor([[2.0, 1.0, 0.5]]))[0]
    np.testing.assert_allclose(sigma.numpy(), np.diag([1.0, 4.0, 0.25]), atol=1e-6)


def test_subsample_keeps_the_most_opaque_and_largest():
    gaussians = random_gaussians(50, 0)
    gaussians.opacities[:], gaussians.scales[:] = 0.5, 0.1
    gaussians.opacities[7] = 1.0
    gaussians.scales[3] *= 100
    kept = select_splats(gaussians, 2)
    assert len(kept) == 2
    assert {tuple(m.tolist()) for m in kept.means} == {tuple(gaussians.means[i].tolist()) for i in (3, 7)}
    assert select_splats(gaussians, 50) is gaussians
    with pytest.raises(ValueError):
        select_splats(gaussians, 0)


def test_transparent_huge_gaussians_are_kept_last_not_first():
    """opacity 0 x an area beyond float32 (scales of 1e26) was NaN, which topk ranks above all."""
    gaussians = random_gaussians(50, 0)
    gaussians.opacities[:], gaussians.scales[:] = 0.5, 0.1
    gaussians.opacities[:10], gaussians.scales[:10] = 0.0, 1e26
    gaussians.scales[5:10] = math.inf  # -inf + inf: NaN again, in a caller's tensor
    kept = select_splats(gaussians, 40)
    assert bool((kept.opacities > 0).all())


def test_arrays_in_the_viewer_frame():
    gaussians = random_gaussians(1000, 1)
    frame = frame_scene(gaussians, None)
    arrays = splat_arrays(gaussians, frame.centre, frame.scale, max_splats=300)
    assert len(arrays) == 300 and arrays.total == 1000
    assert arrays.covariances.shape == (300, 3, 3) and arrays.opacities.shape == (300, 1)
    assert arrays.rgbs.min() >= 0 and arrays.rgbs.max() <= 1
    distances = np.linalg.norm(frame.points(gaussians.means), axis=1)
    assert np.quantile(distances, 0.9) == pytest.approx(VIEWER_RADIUS, rel=0.02)


def test_a_huge_gaussian_reaches_the_browser_as_finite_float16():
    """viser stores covariances as float16: a log-scale of 10 (std 22,000) once overflowed to inf."""
    gaussians = random_gaussians(50, 0)
    gaussians.scales[0] = 22026.0
    frame = frame_scene(gaussians, None)
    arrays = splat_arrays(gaussians, frame.centre, frame.scale)
    assert np.isfinite(arrays.covariances.astype(np.float16)).all()
    assert np.linalg.eigvalsh(arrays.covariances.astype(np.float64)).min() > -1e-6  # still a covariance
    rest = splat_arrays(gaussians.select(torch.arange(1, 50)), frame.centre, frame.scale)
    np.testing.assert_array_equal(rest.covariances, arrays.covariances[1:])  # ordinary splats untouched


def test_a_gaussian_too_far_for_float32_is_left_out_not_sent_as_infinity(caplog):
    gaussians = random_gaussians(50, 0)
    gaussians.means[4] = torch.tensor([1e38, 0.0, 0.0])
    frame = frame_scene(gaussians, None)
    arrays = splat_arrays(gaussians, frame.centre, frame.scale)
    assert len(arrays) == 49 and arrays.total == 50 and np.isfinite(arrays.centers).all()
    assert "1 Gaussian(s) lie too far from the scene for the viewer" in caplog.text


def test_up_is_the_cameras_minus_y():
    # Cameras rolled upside down (180 degrees about z): their -y points along world +y.
    extrinsics = torch.diag(torch.tensor([-1.0, -1.0, 1.0], dtype=torch.float64))[None].expand(2, 3, 3)
    cameras = Cameras(torch.cat([extrinsics, torch.zeros(2, 3, 1, dtype=torch.float64)], 2),
                      make_intrinsics([100.0] * 2, [100.0] * 2, [50.0] * 2, [40.0] * 2), [(100, 80)] * 2)
    np.testing.assert_allclose(camera_up(cameras), [0.0, 1.0, 0.0], atol=1e-9)
    assert frame_scene(random_gaussians(10, 0), None).up.tolist() == [0.0, -1.0, 0.0]
