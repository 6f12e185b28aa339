"""The loss and the working resolution."""

import pytest
import torch

from lumos3d_cli.io.cameras import Cameras, make_intrinsics
from lumos3d_cli.losses.ssim import ssim_map_mean
from lumos3d_cli.refine.photometric import photometric_loss, working_size, working_views


def test_loss_is_l1_and_ssim_weighted():
    generator = torch.Generator().manual_seed(0)
    a, b = torch.rand(2, 3, 20, 24, generator=generator), torch.rand(2, 3, 20, 24, generator=generator)
    expected = 0.8 * (a - b).abs().mean() + 0.2 * (1 - ssim_map_mean(a, b).mean())
    torch.testing.assert_close(photometric_loss(a, b, 0.2), expected)
    torch.testing.assert_close(photometric_loss(a, b, 0.0), (a - b).abs().mean())
    assert photometric_loss(a, a, 0.2).item() == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("size, max_side, expected", [
    ((500, 375), 256, (256, 192)), ((250, 188), 256, (250, 188)), ((375, 500), 100, (75, 100)),
])
def test_working_size_keeps_the_aspect_and_never_enlarges(size, max_side, expected):
    assert working_size(*size, max_side) == expected


def test_working_size_leaves_ssim_room():
    # a panorama keeps 11 pixels (SSIM's window) on its short side, its long side beyond max_side
    assert working_size(4000, 50, 256) == (880, 11) and working_size(500, 40, 64) == (138, 11)
    assert working_size(2000, 11, 256) == (2000, 11)  # never enlarged
    with pytest.raises(ValueError, match="SSIM"):
        working_size(500, 10, 256)  # the targets themselves leave no room


def test_working_views_downsample_targets_and_rescale_cameras():
    targets = torch.rand(1, 3, 40, 60)
    cameras = Cameras(torch.eye(4, dtype=torch.float64)[:3][None], make_intrinsics(50.0, 50.0, 30.0, 20.0), [(60, 40)])
    images, working = working_views(targets, cameras, 30)
    assert images.shape == (1, 3, 20, 30) and working.sizes == [(30, 20)]
    torch.testing.assert_close(images[0, :, 0, 0], targets[0, :, :2, :2].mean(dim=(1, 2)))
    assert working.intrinsics[0, 0, 0].item() == pytest.approx(25.0)

