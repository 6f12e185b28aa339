import cv2
import numpy as np
import pytest
import torch
from skimage import color
from skimage.color import colorconv

from lumos3d_cli.io.colour import linear_to_srgb, luma, luminance, srgb_to_linear


def _skimage_decode(encoded: np.ndarray) -> np.ndarray:
    """Independent oracle: scikit-image's sRGB -> XYZ; for grey pixels Y equals the linear value."""
    grey = np.repeat(encoded.reshape(1, -1, 1), 3, axis=2)
    return color.rgb2xyz(grey)[0, :, 1]


def _skimage_encode(linear: np.ndarray) -> np.ndarray:
    """Independent oracle: scikit-image's XYZ -> sRGB applied to the XYZ of linear grey."""
    xyz = np.repeat(linear.reshape(-1, 1), 3, axis=1) @ colorconv.xyz_from_rgb.T
    return color.xyz2rgb(xyz.reshape(1, -1, 3))[0, :, 0]


def test_known_values_of_the_standard():
    assert srgb_to_linear(np.float64(0.5)) == pytest.approx(0.21404114048223255, abs=1e-15)
    assert linear_to_srgb(np.float64(0.18)) == pytest.approx(0.46135612950044164, abs=1e-15)
    assert srgb_to_linear(np.float64(0.04045)) == pytest.approx(0.04045 / 12.92, abs=1e-15)
    assert linear_to_srgb(np.float64(1.0)) == pytest.approx(1.0, abs=1e-15)
    assert srgb_to_linear(np.float64(0.0)) == 0.0


def test_matches_scikit_image():
    values = np.linspace(0, 1, 4097)
    np.testing.assert_allclose(srgb_to_linear(values), _skimage_decode(values), atol=1e-12)
    np.testing.assert_allclose(linear_to_srgb(values), _skimage_encode(values), atol=1e-9)


def test_round_trip_numpy_and_torch_agree():
    values = np.random.default_rng(0).uniform(0, 1, 10000)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(values)), values, atol=1e-12)
    tensor = torch.from_numpy(values)
    assert torch.allclose(srgb_to_linear(tensor), torch.from_numpy(srgb_to_linear(values)), atol=0, rtol=1e-15)
    assert torch.allclose(linear_to_srgb(tensor), torch.from_numpy(linear_to_srgb(values)), atol=0, rtol=1e-15)


def test_dtype_is_kept():
    assert srgb_to_linear(np.zeros(3, np.float32)).dtype == np.float32
    assert linear_to_srgb(torch.zeros(3, dtype=torch.bfloat16)).dtype == torch.bfloat16


def test_gradients_are_finite_at_black_and_white():
    x = torch.tensor([0.0, 1e-12, 0.0031308, 0.04045, 1.0], dtype=torch.float64, requires_grad=True)
    (linear_to_srgb(x).sum() + srgb_to_linear(x).sum()).backward()
    assert torch.isfinite(x.grad).all()


def test_curve_is_continuous_at_the_knees():
    below, above = np.float64(0.0031308) * (1 - 1e-9), np.float64(0.0031308) * (1 + 1e-9)
    assert abs(linear_to_srgb(above) - linear_to_srgb(below)) < 1e-7
    below, above = np.float64(0.04045) * (1 - 1e-9), np.float64(0.04045) * (1 + 1e-9)
    assert abs(srgb_to_linear(above) - srgb_to_linear(below)) < 1e-7


def test_luma_is_opencvs_grey_and_luminance_rec709_for_numpy_and_torch():
    rgb = np.random.default_rng(3).random((5, 7, 3), dtype=np.float32)
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    chw = np.ascontiguousarray(rgb.transpose(2, 0, 1))
    np.testing.assert_allclose(luma(chw)[0], grey, atol=1e-6)
    np.testing.assert_allclose(luma(torch.from_numpy(chw))[0].numpy(), grey, atol=1e-6)
    expected = 0.2126 * chw[0] + 0.7152 * chw[1] + 0.0722 * chw[2]
    np.testing.assert_allclose(luminance(chw[None])[0, 0], expected, atol=1e-6)
    assert luminance(torch.from_numpy(chw)[None].double()).shape == (1, 1, 5, 7)
