import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.model.appearance.curve import CURVE_KNOTS
from lumos3d_cli.model.appearance.operator import AppearanceOperator
from lumos3d_cli.io.colour import srgb_to_linear
from lumos3d_cli.model.appearance.photo_restoration import frames_without_content, is_monochrome, restore_photos


def _operator(views=3, seed=0) -> AppearanceOperator:
    generator = torch.Generator().manual_seed(seed)
    return AppearanceOperator.from_raw(
        torch.randn(1, 3, CURVE_KNOTS - 1, generator=generator), torch.randn(1, 3, 3, generator=generator) * 0.3,
        torch.randn(1, views, 1, 8, 8, generator=generator),
    )


def test_equals_the_batched_operator_at_any_resolution():
    operator = _operator()
    photos = torch.rand(3, 3, 61, 90, generator=torch.Generator().manual_seed(1))
    restored = restore_photos(photos, operator)
    assert restored.shape == photos.shape and restored.dtype == torch.float32
    torch.testing.assert_close(restored, operator.apply(photos[None])[0])


def test_black_and_saturated_frames_are_found_and_restore_to_finite_values():
    """(The restore job warns of such photos by file name: tests/safety/test_bad_input.py.)"""
    photos = torch.rand(3, 3, 16, 16)
    photos[0] = 0.002  # below one 8-bit step
    photos[2] = 1.0
    assert frames_without_content(photos) == ([0], [2])
    assert frames_without_content(torch.rand(2, 3, 16, 16) * 0.05) == ([], [])
    # within one 8-bit step of black, but in the hundreds of levels a 16-bit file holds: an image
    sixteen_bit = torch.randint(0, 250, (1, 3, 16, 16)) / 65535.0
    assert float(sixteen_bit.max()) <= 1 / 255 and frames_without_content(sixteen_bit) == ([], [])
    # two 8-bit levels (codes 0 and 1; 254 and 255) are still nothing recorded
    assert frames_without_content(torch.randint(0, 2, (1, 3, 16, 16)) / 255.0) == ([0], [])
    assert frames_without_content(torch.randint(254, 256, (1, 3, 16, 16)) / 255.0) == ([], [0])
    # a lens cap's frame: codes 0 to 2 of sensor noise (fused, it spread speckle over other views)
    assert frames_without_content(torch.randint(0, 3, (1, 3, 64, 64)) / 255.0) == ([0], [])
    assert frames_without_content(torch.randint(253, 256, (1, 3, 64, 64)) / 255.0) == ([], [0])
    assert frames_without_content(torch.randint(0, 4, (1, 3, 64, 64)) / 255.0) == ([], [])  # code 3: recorded
    assert frames_without_content(torch.randint(0, 500, (1, 3, 64, 64)) / 65535.0) == ([], [])  # 16-bit: an image
    restored = restore_photos(photos, _operator())
    assert bool(torch.isfinite(restored).all())
    # nothing recorded, nothing restored: the operator's curve would turn the white frame grey
    assert torch.equal(restored[0], photos[0]) and torch.equal(restored[2], photos[2])
    torch.testing.assert_close(restored[1], _operator().apply(photos[None])[0, 1])


def test_refuses_mismatched_inputs():
    with pytest.raises(InputError, match="one scene"):
        restore_photos(torch.rand(3, 3, 8, 8), AppearanceOperator.identity(2))
    with pytest.raises(InputError, match="local grids for 3 views"):
        restore_photos(torch.rand(2, 3, 8, 8), _operator(3))
    with pytest.raises(InputError, match=r"\[V, 3, H, W\]"):
        restore_photos(torch.rand(3, 8, 8), _operator(3))


def test_a_monochrome_photo_restores_grey_with_the_operators_luminance():
    """A tinting operator (random matrix) on a greyscale photo: the output is grey in every
    pixel, and its linear luminance is the operator's own output's (Rec. 709 weights)."""
    generator = torch.Generator().manual_seed(2)
    grey = torch.rand(1, 1, 24, 32, generator=generator).expand(1, 3, 24, 32) * 0.3
    colour = torch.rand(1, 3, 24, 32, generator=generator) * 0.3
    photos = torch.cat([grey, colour])
    operator = _operator(views=2)
    assert is_monochrome(photos[0]) and not is_monochrome(photos[1])
    assert not is_monochrome(photos[0] + torch.tensor([0.0, 0.0, 1.5 / 255]).reshape(3, 1, 1))
    # a dark 16-bit colour photo lies within one 8-bit step too, but its channels differ in proportion
    dark_colour = (colour[0] / colour[0].max() / 255 * torch.tensor([1.0, 0.7, 0.5]).reshape(3, 1, 1) * 65535).round() / 65535
    assert float((dark_colour.amax(0) - dark_colour.amin(0)).max()) <= 1 / 255 and not is_monochrome(dark_colour)
    restored = restore_photos(photos, operator)
    expected = operator.apply(photos[None])[0]
    assert float((expected[0].amax(0) - expected[0].amin(0)).max()) > 0.02  # the operator does tint it
    assert torch.equal(restored[0][0], restored[0][1]) and torch.equal(restored[0][1], restored[0][2])
    weights = torch.tensor([0.2126, 0.7152, 0.0722]).reshape(3, 1, 1)
    torch.testing.assert_close((srgb_to_linear(restored[0]) * weights).sum(0),
                               (srgb_to_linear(expected[0]) * weights).sum(0), atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(restored[1], expected[1])  # colour photos are untouched
