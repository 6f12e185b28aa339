import numpy as np
import pytest
import torch

from lumos3d_cli.model.appearance.curve import (
    CURVE_KNOTS, MAX_GAIN, apply_curve, bound_slopes, curve_knots, curve_values, raw_for_slopes,
)


def _as_images(x: torch.Tensor) -> torch.Tensor:
    """[N] values -> [1, 1, 3, 1, N] (the same values in every channel)."""
    return x.reshape(1, 1, 1, 1, -1).expand(1, 1, 3, 1, -1).contiguous()


def test_knots_start_at_zero_end_at_one_and_give_at_least_16_segments():
    knots = curve_knots()
    assert CURVE_KNOTS - 1 >= 16
    assert knots[0] == 0 and knots[-1] == 1
    assert bool((knots[1:] > knots[:-1]).all())
    ratios = knots[2:] / knots[1:-1]
    torch.testing.assert_close(ratios, torch.full_like(ratios, float(ratios[0])))  # log-spaced


def test_zero_parameters_are_the_identity():
    x = torch.linspace(0, 1.5, 2001)
    slopes = bound_slopes(torch.zeros(1, 3, CURVE_KNOTS - 1))
    torch.testing.assert_close(apply_curve(_as_images(x), slopes, curve_knots()), _as_images(x))


@pytest.mark.parametrize("seed", range(5))
def test_monotone_and_bounded_for_any_parameters(seed):
    generator = torch.Generator().manual_seed(seed)
    raw = torch.randn(2, 3, CURVE_KNOTS - 1, generator=generator) * 10 ** (seed - 2)
    slopes = bound_slopes(raw)
    assert bool((slopes >= 1 / MAX_GAIN - 1e-6).all()) and bool((slopes <= MAX_GAIN * (1 + 1e-6)).all())
    x = torch.cat((torch.zeros(1), torch.logspace(-16, 0.2, 4000, base=2.0)))
    images = _as_images(x).expand(2, 1, 3, 1, -1)
    out = apply_curve(images, slopes, curve_knots())
    steps = out[..., 1:] - out[..., :-1]
    assert bool((steps > 0).all())
    assert bool((out[..., 0] == 0).all())  # black stays black
    # The gain x -> f(x) / x never exceeds the slope bound (f(0) = 0 and every slope is bounded).
    assert bool((out[..., 1:] / x[1:] <= MAX_GAIN * (1 + 1e-5)).all())


def test_matches_numpy_interpolation():
    generator = torch.Generator().manual_seed(3)
    slopes = bound_slopes(torch.randn(1, 3, CURVE_KNOTS - 1, generator=generator))
    knots = curve_knots().double().numpy()
    x = np.random.default_rng(0).uniform(0, 1, 5000)
    out = apply_curve(_as_images(torch.from_numpy(x).float()), slopes, curve_knots())
    for channel in range(3):
        widths = np.diff(knots)
        values = np.concatenate(([0.0], np.cumsum(slopes[0, channel].double().numpy() * widths)))
        np.testing.assert_allclose(out[0, 0, channel, 0].numpy(), np.interp(x, knots, values), rtol=1e-5, atol=1e-6)


def test_constant_slope_is_a_pure_gain_also_above_one():
    slopes = torch.full((1, 3, CURVE_KNOTS - 1), 20.0)
    x = torch.linspace(0, 1.2, 500)
    torch.testing.assert_close(apply_curve(_as_images(x), slopes, curve_knots()), 20 * _as_images(x))
    values = curve_values(slopes, curve_knots())
    torch.testing.assert_close(values[0, 0, -1], torch.tensor(20.0))


def test_raw_for_slopes_inverts_the_bound():
    slopes = torch.tensor([1 / 32, 0.5, 1.0, 3.0, 40.0])
    torch.testing.assert_close(bound_slopes(raw_for_slopes(slopes)), slopes, rtol=1e-4, atol=0)
    assert bool(torch.isfinite(raw_for_slopes(torch.tensor([MAX_GAIN, 1 / MAX_GAIN, 1e9]))).all())


def test_negative_inputs_are_black_and_gradients_are_finite():
    raw = torch.zeros(1, 3, CURVE_KNOTS - 1, requires_grad=True)
    x = torch.tensor([-0.5, 0.0, 2.0**-20, 0.5, 1.0, 3.0])
    out = apply_curve(_as_images(x), bound_slopes(raw), curve_knots())
    assert bool((out[..., 0] == 0).all())
    out.sum().backward()
    assert bool(torch.isfinite(raw.grad).all()) and float(raw.grad.abs().sum()) > 0
