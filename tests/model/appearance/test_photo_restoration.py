import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.model.appearance.curve import CURVE_KNOTS
from lumos3d_cli.model.appearance.operator import AppearanceOperator
from lumos3d_cli.model.appearance.photo_restoration import frames_without_content, restore_photos


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
