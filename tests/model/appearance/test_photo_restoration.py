import logging

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


def test_warns_about_black_and_saturated_frames(caplog):
    photos = torch.rand(3, 3, 16, 16)
    photos[0] = 0.002  # below one 8-bit step
    photos[2] = 1.0
    assert frames_without_content(photos) == ([0], [2])
    with caplog.at_level(logging.WARNING):
        restored = restore_photos(photos, _operator())
    assert "0 are entirely black" in caplog.text and "2 are entirely saturated" in caplog.text
    assert bool(torch.isfinite(restored).all())


def test_no_warning_for_ordinary_dark_photos(caplog):
    photos = torch.rand(2, 3, 16, 16) * 0.05
    with caplog.at_level(logging.WARNING):
        restore_photos(photos, _operator(2))
    assert caplog.text == ""


def test_refuses_mismatched_inputs():
    with pytest.raises(InputError, match="one scene"):
        restore_photos(torch.rand(3, 3, 8, 8), AppearanceOperator.identity(2))
    with pytest.raises(InputError, match="local grids for 3 views"):
        restore_photos(torch.rand(2, 3, 8, 8), _operator(3))
    with pytest.raises(InputError, match=r"\[V, 3, H, W\]"):
        restore_photos(torch.rand(3, 8, 8), _operator(3))
