import pytest
import torch

from lumos3d_cli.io.colour import linear_to_srgb, srgb_to_linear
from lumos3d_cli.model.appearance.curve import CURVE_KNOTS, MAX_GAIN
from lumos3d_cli.model.appearance.local_correction import LOCAL_MAX_STOPS
from lumos3d_cli.model.appearance import operator as operator_module
from lumos3d_cli.model.appearance.operator import MATRIX_BOUND, AppearanceOperator


def _images(batch=2, views=3, height=20, width=24, seed=0) -> torch.Tensor:
    return torch.rand(batch, views, 3, height, width, generator=torch.Generator().manual_seed(seed))


def _random_operator(batch=2, views=3, scale=3.0, seed=0, local_channels=1) -> AppearanceOperator:
    generator = torch.Generator().manual_seed(seed)
    return AppearanceOperator.from_raw(
        torch.randn(batch, 3, CURVE_KNOTS - 1, generator=generator) * scale,
        torch.randn(batch, 3, 3, generator=generator) * scale,
        torch.randn(batch, views, local_channels, 8, 8, generator=generator) * scale,
    )


def test_zero_parameters_return_the_input():
    images = _images()
    for operator in (
        AppearanceOperator.identity(2, views=3),
        AppearanceOperator.from_raw(torch.zeros(2, 3, CURVE_KNOTS - 1), torch.zeros(2, 3, 3), torch.zeros(2, 3, 3, 8, 8)),
    ):
        torch.testing.assert_close(operator.apply(images), images, atol=2e-6, rtol=0)


def test_a_gain_operator_matches_the_linear_light_oracle():
    images = _images(1, 2)
    gains = torch.tensor([8.0, 5.0, 12.0])
    operator = AppearanceOperator(gains.view(1, 3, 1).expand(1, 3, CURVE_KNOTS - 1).clone(), torch.eye(3)[None])
    expected = linear_to_srgb((srgb_to_linear(images.double()) * gains.double().view(3, 1, 1)).clamp(0, 1))
    torch.testing.assert_close(operator.apply(images).double(), expected, atol=1e-5, rtol=0)


def test_the_matrix_acts_before_the_curve_in_linear_light():
    # A pure channel mix (no gain): output linear = M @ input linear, clipped at 0.
    matrix = torch.tensor([[1.2, 0.1, -0.1], [0.0, 0.9, 0.05], [-0.2, 0.0, 1.1]])
    operator = AppearanceOperator(torch.ones(1, 3, CURVE_KNOTS - 1), matrix[None])
    images = 0.75 * _images(1, 1)  # below the bright range, where the photo's hue is kept (clipped_highlights)
    linear = srgb_to_linear(images.double())
    expected = linear_to_srgb(torch.einsum("ij,bvjhw->bvihw", matrix.double(), linear).clamp(0, 1))
    torch.testing.assert_close(operator.apply(images).double(), expected, atol=1e-5, rtol=0)


@pytest.mark.parametrize("scale", [0.1, 3.0, 1e4])
def test_bounds_hold_for_any_raw_parameters(scale):
    operator = _random_operator(scale=scale)
    assert bool((operator.curve_slopes <= MAX_GAIN * (1 + 1e-6)).all() and (operator.curve_slopes >= 1 / MAX_GAIN * (1 - 1e-6)).all())
    assert bool(((operator.matrix - torch.eye(3)).abs() <= MATRIX_BOUND + 1e-6).all())
    assert bool((operator.local_log2_gain.abs() <= LOCAL_MAX_STOPS + 1e-6).all())
    out = operator.apply(_images())
    assert out.dtype == torch.float32 and bool(torch.isfinite(out).all())
    assert float(out.min()) >= 0 and float(out.max()) <= 1


def test_monotone_in_brightness_for_a_grey_ramp():
    # With a non-negative matrix, more light in every channel never gives less light out.
    operator = _random_operator(1, 1, seed=4)
    operator.matrix = operator.matrix.clamp_min(0)
    ramp = torch.linspace(0, 1, 300).view(1, 1, 1, 1, -1).expand(1, 1, 3, 1, -1)
    operator.local_log2_gain = operator.local_log2_gain[..., :1, :1]  # one gain for the whole ramp
    out = operator.apply(ramp)
    assert bool((out[..., 1:] - out[..., :-1] >= -1e-6).all())


def test_black_and_saturated_frames_stay_finite_and_sensible():
    operator = _random_operator(1, 2, scale=2.0, seed=1)
    frames = torch.stack((torch.zeros(3, 16, 16), torch.ones(3, 16, 16)))[None]
    out = operator.apply(frames)
    assert bool(torch.isfinite(out).all())
    assert float(out[0, 0].abs().max()) == 0  # no gain lifts black
    assert float(out[0, 1].min()) > 0


def test_bf16_autocast_computes_in_float32():
    operator = _random_operator(seed=2)
    images = _images()
    expected = operator.apply(images)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = operator.apply(images.bfloat16())
    assert out.dtype == torch.float32 and bool(torch.isfinite(out).all())
    # Only the bf16 rounding of the input photo differs (relative 2^-9, amplified by the gain).
    assert float((out - expected).abs().mean()) < 0.01


def test_scene_views_and_shape_checks():
    operator = _random_operator(batch=2, views=3)
    one = operator.scene(1)
    assert one.batch == 1 and one.local_log2_gain.shape == (1, 3, 1, 8, 8)
    images = _images()
    torch.testing.assert_close(one.apply(images[1:]), operator.apply(images)[1:])
    torch.testing.assert_close(one.views(slice(2, 3)).apply(images[1:, 2:]), operator.apply(images)[1:, 2:])
    with pytest.raises(ValueError, match="scenes"):
        one.apply(images)
    with pytest.raises(ValueError, match="views"):
        one.apply(images[1:, :2])


def test_gradients_reach_every_parameter():
    raw = [torch.zeros(1, 3, CURVE_KNOTS - 1, requires_grad=True), torch.zeros(1, 3, 3, requires_grad=True),
           torch.zeros(1, 2, 1, 8, 8, requires_grad=True)]
    out = AppearanceOperator.from_raw(*raw).apply(_images(1, 2) * 0.5)
    out.mean().backward()
    for parameter in raw:
        assert bool(torch.isfinite(parameter.grad).all()) and float(parameter.grad.abs().sum()) > 0


@pytest.mark.parametrize("band", [1, 7 * 3 * 24, 10**9])  # one row a band, a band of 7 rows, one band
def test_restoring_in_bands_of_rows_gives_the_whole_images_result_and_gradients(monkeypatch, band):
    """Full-resolution photos are restored in bands of rows (a 27-MP view held 3 GB of temporaries)."""
    images = _images(1, 3, height=20, width=24) * 1.2  # some near-clipped pixels: their chromaticity is kept
    raw = [torch.randn(1, 3, CURVE_KNOTS - 1) * 2, torch.randn(1, 3, 3), torch.randn(1, 3, 1, 8, 8)]
    monkeypatch.setattr(operator_module, "_PIXELS_PER_BAND", 10**9)
    parameters = [tensor.clone().requires_grad_(True) for tensor in raw]
    whole = AppearanceOperator.from_raw(*parameters).apply(images.clamp(0, 1))
    whole.square().mean().backward()
    monkeypatch.setattr(operator_module, "_PIXELS_PER_BAND", band)
    banded_parameters = [tensor.clone().requires_grad_(True) for tensor in raw]
    banded = AppearanceOperator.from_raw(*banded_parameters).apply(images.clamp(0, 1))
    banded.square().mean().backward()
    torch.testing.assert_close(banded, whole, atol=1e-6, rtol=0)
    for ours, theirs in zip(banded_parameters, parameters):
        torch.testing.assert_close(ours.grad, theirs.grad, atol=1e-6, rtol=1e-5)


def test_require_finite_names_the_part():
    operator = _random_operator()
    operator.matrix[0, 0, 0] = float("nan")
    with pytest.raises(Exception, match="matrix"):
        operator.require_finite()
