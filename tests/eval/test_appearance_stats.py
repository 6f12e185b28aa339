import math

import numpy as np
import pytest
import torch
from skimage.color import rgb2lab

from lumos3d_cli.eval.appearance_stats import appearance_stats, brightness_stops, mean_chroma, mean_linear_luminance


def _srgb_decode(value: float) -> float:
    """IEC 61966-2-1 by hand, independent of io.colour."""
    return value / 12.92 if value <= 0.04045 else ((value + 0.055) / 1.055) ** 2.4


def _flat(r: float, g: float, b: float, size: int = 16) -> torch.Tensor:
    return torch.tensor([r, g, b], dtype=torch.float32)[:, None, None].expand(3, size, size).clone()


def test_stops_by_hand():
    grey_half = _flat(0.5, 0.5, 0.5)
    # one stop: a linear value twice the other's, both encoded in sRGB
    encoded = 1.055 * (2 * _srgb_decode(0.5)) ** (1 / 2.4) - 0.055
    assert brightness_stops(_flat(encoded, encoded, encoded), grey_half).item() == pytest.approx(1.0, abs=1e-5)
    assert brightness_stops(grey_half, _flat(encoded, encoded, encoded)).item() == pytest.approx(-1.0, abs=1e-5)
    assert brightness_stops(grey_half, grey_half).item() == 0.0
    # coloured pixels: Rec. 709 luminance of the decoded channels, means over the whole image
    image = torch.zeros(3, 4, 4)
    image[:, :2] = torch.tensor([0.8, 0.2, 0.1])[:, None, None]
    image[:, 2:] = torch.tensor([0.1, 0.3, 0.9])[:, None, None]
    luminance = [0.2126 * _srgb_decode(r) + 0.7152 * _srgb_decode(g) + 0.0722 * _srgb_decode(b)
                 for r, g, b in ((0.8, 0.2, 0.1), (0.1, 0.3, 0.9))]
    expected_mean = sum(luminance) / 2
    assert mean_linear_luminance(image).item() == pytest.approx(expected_mean, rel=1e-6)
    reference = _flat(0.6, 0.6, 0.6, 4)
    expected = math.log2(expected_mean / _srgb_decode(0.6))
    assert brightness_stops(image, reference).item() == pytest.approx(expected, abs=1e-6)


def test_stops_shapes_and_black():
    rng = torch.Generator().manual_seed(0)
    images = torch.rand(2, 3, 3, 8, 8, generator=rng)
    assert brightness_stops(images, images).shape == (2, 3)
    assert torch.allclose(brightness_stops(images, images), torch.zeros(2, 3, dtype=torch.float64))
    assert brightness_stops(torch.zeros(3, 4, 4), _flat(0.5, 0.5, 0.5, 4)).item() == -math.inf


def test_chroma_matches_scikit_image():
    rng = np.random.default_rng(1)
    pixels = rng.random((24, 32, 3))
    # a smooth gradient of saturated colours too, beside the noise
    pixels[:12] = np.stack([*np.meshgrid(np.linspace(0, 1, 32), np.linspace(1, 0, 12)), np.full((12, 32), 0.2)], -1)
    lab = rgb2lab(pixels)  # float64, D65, sRGB transfer function
    expected = np.hypot(lab[..., 1], lab[..., 2]).mean()
    ours = mean_chroma(torch.from_numpy(pixels).permute(2, 0, 1).float()).item()
    assert ours == pytest.approx(expected, rel=2e-3)


def test_chroma_of_grey_and_of_a_pure_colour():
    # OpenCV's float path is off by a few hundredths of a unit on grey (photos score 5-40)
    assert mean_chroma(_flat(0.4, 0.4, 0.4)).item() == pytest.approx(0.0, abs=0.1)
    red = rgb2lab(np.array([[[1.0, 0.0, 0.0]]]))[0, 0]
    assert mean_chroma(_flat(1.0, 0.0, 0.0)).item() == pytest.approx(math.hypot(red[1], red[2]), rel=2e-3)
    batch = torch.stack([_flat(1.0, 0.0, 0.0), _flat(0.4, 0.4, 0.4)])
    assert mean_chroma(batch[None]).shape == (1, 2)


def test_appearance_stats_rows():
    saturated, washed = _flat(0.8, 0.3, 0.2), _flat(0.6, 0.45, 0.4)
    rows = appearance_stats(torch.stack([washed, saturated]), torch.stack([saturated, saturated]))
    assert rows[0]["chroma_ratio"] < 0.6 and rows[1]["chroma_ratio"] == pytest.approx(1.0)
    assert rows[1]["stops"] == 0.0 and rows[0]["chroma_reference"] == pytest.approx(rows[1]["chroma"])
    assert math.isnan(appearance_stats([saturated], [_flat(0.0, 0.0, 0.0)])[0]["chroma_ratio"])
    with pytest.raises(ValueError):
        appearance_stats([saturated], [])
