import numpy as np
import torch

from lumos3d_cli.model.appearance.footprint import footprint_colours


def test_box_means_for_integer_factors():
    photos = torch.rand(2, 3, 40, 60, generator=torch.Generator().manual_seed(0))
    out = footprint_colours(photos, 10, 15)
    expected = photos.numpy().reshape(2, 3, 10, 4, 15, 4).mean(axis=(3, 5))
    np.testing.assert_allclose(out.numpy(), expected, rtol=1e-6, atol=1e-6)


def test_non_integer_factors_keep_the_mean_and_constants():
    photos = torch.full((1, 3, 37, 53), 0.3)
    torch.testing.assert_close(footprint_colours(photos, 12, 16), torch.full((1, 3, 12, 16), 0.3))
    ramp = torch.linspace(0, 1, 53).expand(1, 3, 37, 53)
    assert abs(float(footprint_colours(ramp, 12, 16).mean()) - 0.5) < 0.02


def test_small_photos_are_enlarged():
    out = footprint_colours(torch.rand(1, 3, 8, 8), 16, 16)
    assert out.shape == (1, 3, 16, 16) and bool(torch.isfinite(out).all())
