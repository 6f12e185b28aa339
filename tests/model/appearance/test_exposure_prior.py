"""The exposure prior (model.appearance.exposure_prior): a gain per scene that pulls the restored
brightness towards a key. Oracle: the sRGB encoding written out from IEC 61966-2-1 in numpy."""

import numpy as np
import pytest
import torch

from lumos3d_cli.io.colour import linear_to_srgb
from lumos3d_cli.model.appearance.curve import CURVE_KNOTS
from lumos3d_cli.model.appearance.exposure_prior import (
    EXPOSURE_KEY,
    MAX_NEWLY_CLIPPED,
    MAX_PRIOR_STOPS,
    apply_exposure_prior,
    exposure_prior_stops,
    highlight_headroom,
    stops_to_key,
)
from lumos3d_cli.model.appearance.operator import AppearanceOperator


def _srgb_mean(linear: np.ndarray) -> float:
    """IEC 61966-2-1 encoding of clip(linear), averaged."""
    x = np.clip(linear, 0.0, 1.0)
    return float(np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055).mean())


def _dark_scene(seed=0, views=3, level=0.02) -> torch.Tensor:
    """[1, V, 3, H, W] linear light: a dim, textured scene."""
    generator = torch.Generator().manual_seed(seed)
    return level * torch.rand(1, views, 3, 16, 20, generator=generator, dtype=torch.float64) ** 2


def test_the_gain_brings_each_scene_to_the_key():
    scenes = torch.cat([_dark_scene(0, level=0.2), _dark_scene(1, level=1.0), _dark_scene(2, level=6.0)])
    stops = stops_to_key(scenes)
    for scene, stop in zip(scenes.numpy(), stops.tolist()):
        assert abs(_srgb_mean(scene * 2.0**stop) - EXPOSURE_KEY) < 1e-5
    assert stops[0] > 0 > stops[2]


def test_a_uniform_grey_scene_gets_the_analytic_gain():
    target = ((EXPOSURE_KEY + 0.055) / 1.055) ** 2.4  # the linear value whose sRGB is the key
    stops = stops_to_key(torch.full((1, 2, 3, 4, 4), 0.03))
    assert stops.item() == pytest.approx(np.log2(target / 0.03), abs=1e-5)


def test_scenes_with_nothing_to_meter_get_no_gain_and_the_bound_holds():
    black = torch.zeros(1, 2, 3, 8, 8)
    white = torch.full((1, 2, 3, 8, 8), 4.0)  # all clipped
    speck = torch.zeros(1, 1, 3, 8, 8)
    speck[..., 0, 0] = 0.01  # one dim pixel: no gain within the bound reaches the key
    glare = torch.full((1, 1, 3, 8, 8), 1e6)
    glare[..., 0, 0] = 0.0
    stops = stops_to_key(torch.cat([black, white, speck.expand(1, 2, 3, 8, 8), glare.expand(1, 2, 3, 8, 8)]))
    assert stops[:2].tolist() == [0.0, 0.0]
    assert stops[2].item() == pytest.approx(MAX_PRIOR_STOPS, abs=1e-6)
    assert stops[3].item() == pytest.approx(-MAX_PRIOR_STOPS, abs=1e-6)
    assert torch.isfinite(stops).all()


def _operator(batch=2, views=3, seed=0) -> AppearanceOperator:
    generator = torch.Generator().manual_seed(seed)
    return AppearanceOperator.from_raw(torch.randn(batch, 3, CURVE_KNOTS - 1, generator=generator) * 0.3,
                                       torch.randn(batch, 3, 3, generator=generator) * 0.3,
                                       torch.randn(batch, views, 1, 8, 8, generator=generator) * 0.3)


def test_a_gain_is_exact_on_the_operators_output():
    operator = _operator()
    linear = torch.rand(2, 3, 3, 10, 12, generator=torch.Generator().manual_seed(3))
    gained = operator.with_gain(torch.tensor([1.5, -0.75]))
    expected = operator.apply_linear(linear) * torch.tensor([2**1.5, 2**-0.75]).view(2, 1, 1, 1, 1)
    torch.testing.assert_close(gained.apply_linear(linear), expected, rtol=1e-5, atol=1e-7)


def test_strength_interpolates_in_stops_up_to_the_highlight_headroom():
    from lumos3d_cli.io.colour import srgb_to_linear

    operator = _operator()
    images = 0.4 * torch.rand(2, 3, 3, 16, 20, generator=torch.Generator().manual_seed(4))  # dark sRGB
    restored = operator.apply_linear(srgb_to_linear(images))
    to_key, headroom = stops_to_key(restored), highlight_headroom(restored)
    for strength in (0.25, 0.75, 1.0):
        expected = torch.where(strength * to_key > 0, torch.minimum(strength * to_key, headroom), strength * to_key)
        torch.testing.assert_close(exposure_prior_stops(operator, images, strength), expected)
    assert exposure_prior_stops(operator, images, strength=0.0).tolist() == [0.0, 0.0]
    torch.testing.assert_close(apply_exposure_prior(operator, images, 0.0).apply(images), operator.apply(images))
    with pytest.raises(ValueError, match="strength"):
        exposure_prior_stops(operator, images, strength=1.5)
    # where the highlights leave room, strength 1 lands on the key
    flat = 0.15 + 0.1 * torch.rand(2, 3, 3, 16, 20, generator=torch.Generator().manual_seed(5))
    identity = AppearanceOperator.identity(2)
    for scene in apply_exposure_prior(identity, flat, strength=1.0).apply(flat):
        assert float(scene.mean()) == pytest.approx(EXPOSURE_KEY, abs=2e-4)


def test_bf16_images_and_one_view_give_the_float32_gain():
    operator = _operator(batch=1, views=1)
    images = 0.1 * torch.rand(1, 1, 3, 16, 20, generator=torch.Generator().manual_seed(5))
    expected = exposure_prior_stops(operator, images, 0.75)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        stops = exposure_prior_stops(operator, images.bfloat16(), 0.75)
    assert stops.dtype == torch.float32 and torch.isfinite(stops).all()
    assert stops.item() == pytest.approx(expected.item(), abs=0.05)  # bf16 rounding of the photo only


def test_brightening_clips_at_most_one_percent_more_of_the_pixels():
    """A night street: lamps already clipped on 3 % of the frame, everything else dark. Metering the
    mean alone would brighten it by stops that clip the lit surfaces around the lamps too."""
    generator = torch.Generator().manual_seed(6)
    scene = 0.01 * torch.rand(1, 2, 3, 50, 40, generator=generator)
    scene[..., :10, :] = 0.3 + 0.2 * torch.rand(1, 2, 3, 10, 40, generator=generator)  # lit walls: 20 %
    scene[..., :3, :16] = 2.0  # lamps: 2.4 %
    clipped_before = float((scene.amax(dim=2) >= 1).float().mean())
    wanted = stops_to_key(scene)
    headroom = highlight_headroom(scene)
    assert wanted > 2 and 0 < headroom < 1.5
    clipped_after = float(((scene * 2.0**headroom).amax(dim=2) >= 1 - 1e-6).float().mean())
    assert clipped_after <= clipped_before + MAX_NEWLY_CLIPPED + 1e-3
    assert float(((scene * 2.0**wanted).amax(dim=2) >= 1).float().mean()) > clipped_before + 0.1
    operator = AppearanceOperator.identity(1)
    images = linear_to_srgb(scene)
    assert exposure_prior_stops(operator, images, strength=1.0).item() == pytest.approx(headroom.item(), abs=1e-3)
    # darkening is never limited, and a scene of nothing but highlights has no headroom
    assert highlight_headroom(torch.full((1, 1, 3, 8, 8), 2.0)).item() == 0.0
    assert highlight_headroom(torch.zeros(1, 1, 3, 8, 8)).item() == MAX_PRIOR_STOPS


def test_a_non_finite_operator_is_named_not_passed_on():
    from lumos3d_cli.errors import NonFiniteError

    operator = _operator(batch=1, views=1)
    operator.curve_slopes[0, 0, 3] = float("nan")
    with pytest.raises(NonFiniteError, match="exposure prior"):
        exposure_prior_stops(operator, torch.full((1, 1, 3, 8, 8), 0.3), 0.75)


def test_black_and_saturated_photos_are_not_metered():
    """One black frame among real ones would pull the mean down and brighten every view; the
    gain is the real frames' own, and a scene of only black or white frames gets none."""
    operator = _operator(batch=1, views=4)
    real = 0.3 * torch.rand(1, 4, 3, 16, 20, generator=torch.Generator().manual_seed(7))
    alone = exposure_prior_stops(AppearanceOperator.identity(1), real[:, :3], 0.75)
    mixed = real.clone()
    mixed[0, 3] = 0.0
    assert exposure_prior_stops(AppearanceOperator.identity(1), mixed, 0.75).item() == pytest.approx(alone.item(), abs=1e-6)
    mixed[0, 3] = 1.0
    assert exposure_prior_stops(AppearanceOperator.identity(1), mixed, 0.75).item() == pytest.approx(alone.item(), abs=1e-6)
    blank = torch.cat([torch.zeros(1, 2, 3, 16, 20), torch.ones(1, 2, 3, 16, 20)], dim=1)
    assert exposure_prior_stops(operator, blank, 1.0).tolist() == [0.0]


def test_the_views_left_unmetered_can_be_named_from_the_photos_themselves():
    """A black frame with a few code-1 hot pixels has two levels at its own size but dozens once
    resized for the network: the restore names it from the photos (`unmetered`)."""
    real = 0.15 + 0.3 * torch.rand(1, 4, 3, 16, 20, generator=torch.Generator().manual_seed(7))  # gains under the cap
    alone = exposure_prior_stops(AppearanceOperator.identity(1), real[:, :3], 0.75)
    resized_black = real.clone()
    resized_black[0, 3] = torch.rand(3, 16, 20, generator=torch.Generator().manual_seed(8)) * 0.2 / 255  # many levels
    named = exposure_prior_stops(AppearanceOperator.identity(1), resized_black, 0.75, unmetered=[{3}])
    assert named.item() == pytest.approx(alone.item(), abs=1e-6)
    assert exposure_prior_stops(AppearanceOperator.identity(1), resized_black, 0.75).item() > alone.item() + 0.1
