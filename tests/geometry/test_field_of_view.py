"""The fallback for fields of view no lens has (geometry.field_of_view)."""

import math

import pytest
import torch

from lumos3d_cli.geometry.field_of_view import FALLBACK_FOV_DEGREES, longer_side_fov, plausible_intrinsics
from lumos3d_cli.model.pose_encoding import MIN_FOV


def _intrinsics(fx: float, fy: float, size: tuple[int, int]) -> torch.Tensor:
    width, height = size
    return torch.tensor([[fx, 0.0, width / 2], [0.0, fy, height / 2], [0.0, 0.0, 1.0]], dtype=torch.float64)


def test_the_longer_side_decides_the_field_of_view():
    # 90 degrees across 200 px needs f = 100; portrait images measure along their height
    landscape = _intrinsics(100.0, 100.0, (200, 100))[None]
    portrait = _intrinsics(100.0, 100.0, (100, 200))[None]
    assert longer_side_fov(landscape, (200, 100)).item() == pytest.approx(90.0)
    assert longer_side_fov(portrait, (100, 200)).item() == pytest.approx(90.0)


def test_plausible_fields_of_view_are_kept_untouched():
    size = (224, 168)
    intrinsics = torch.stack([_intrinsics(f, f * 1.01, size) for f in (45.0, 240.0, 2000.0)])
    fixed, replaced = plausible_intrinsics(intrinsics, size)
    assert fixed is intrinsics and not replaced.any()


def test_degenerate_predictions_get_the_fallback_lens():
    size = (224, 140)
    width, height = size
    # what the camera head decodes from a field of view ReLU'd to 0, a near-180-degree one, and NaN
    zero = (width / 2) / math.tan(MIN_FOV / 2)
    wide = (width / 2) / math.tan((math.pi - MIN_FOV) / 2)
    intrinsics = torch.stack([_intrinsics(zero, zero, size), _intrinsics(240.0, 240.0, size),
                              _intrinsics(wide, wide, size), _intrinsics(float("nan"), 100.0, size)])
    fixed, replaced = plausible_intrinsics(intrinsics, size)
    assert replaced.tolist() == [True, False, True, True]
    assert torch.isfinite(fixed).all()
    assert longer_side_fov(fixed[replaced], size) == pytest.approx(torch.full((3,), FALLBACK_FOV_DEGREES, dtype=torch.float64))
    assert (fixed[replaced, 0, 0] == fixed[replaced, 1, 1]).all()  # square pixels
    assert torch.equal(fixed[:, :2, 2], intrinsics[:, :2, 2])  # principal points kept
    assert torch.equal(fixed[1], intrinsics[1])


def test_a_degenerate_field_of_view_down_alone_gets_square_pixels_at_the_one_across():
    """The head's field of view of the shorter side alone failed (kitchen at 200x134: 134,000 px
    down against 817 across): the longer side was plausible, so the view kept pixels 164:1."""
    size = (200, 134)
    zero = (size[1] / 2) / math.tan(MIN_FOV / 2)
    intrinsics = torch.stack([_intrinsics(817.0, zero, size), _intrinsics(240.0, 250.0, size),
                              _intrinsics(240.0, 500.0, size), _intrinsics(240.0, 100.0, size)])
    fixed, replaced = plausible_intrinsics(intrinsics, size)
    assert replaced.tolist() == [True, False, True, True]
    assert fixed[0, 0, 0] == fixed[0, 1, 1] == 817.0  # the longer side's focal length, square pixels
    assert (fixed[2:, 0, 0] == 240.0).all() and (fixed[2:, 1, 1] == 240.0).all()
    assert torch.equal(fixed[1], intrinsics[1])


def test_views_no_lens_has_are_named_with_their_own_sizes():
    from lumos3d_cli.geometry.field_of_view import implausible_views

    intrinsics = torch.stack([_intrinsics(f, f, (500, 375)) for f in (400.0, 1e5, 0.5, float("nan"))])
    found = implausible_views(intrinsics, [(500, 375), (500, 375), (500, 375), (500, 375)])
    assert list(found) == [1, 2, 3] and found[1] == pytest.approx(math.degrees(2 * math.atan(250 / 1e5)))
    # a portrait photo measures along its height: 60 degrees for the landscape one, 90 for it
    assert implausible_views(torch.stack([_intrinsics(250 * 3 ** 0.5, 250 * 3 ** 0.5, (500, 375)),
                                          _intrinsics(250, 250, (375, 500))]), [(500, 375), (375, 500)]) == {}
    # either side: a focal length of 1e30 px down alone (across 400) rendered black frames unwarned
    found = implausible_views(_intrinsics(400.0, 1e30, (500, 375))[None], [(500, 375)])
    assert list(found) == [0] and found[0] < 1e-20


def test_a_stretched_photo_is_judged_square_at_its_own_size():
    """A portrait 16:9 photo among landscape ones is stretched to the landscape working size: its
    correct camera is far from square there (the check took it for a failed prediction and made
    its camera 1500 x 4698 at its own size); judged at its own size it is kept, and a failed
    one is made square there."""
    size = (512, 288)  # the network's size of 16:9 landscape photos
    own = (288 / 512) / (512 / 288)  # a 288x512 portrait photo's width factor over its height factor
    correct = _intrinsics(300.0, 300.0 * own, size)  # square at its own size
    failed = _intrinsics(300.0, 300.0 * own * 40, size)
    fixed, replaced = plausible_intrinsics(torch.stack([correct, failed]), size, torch.tensor([own, own]))
    assert replaced.tolist() == [False, True]
    assert torch.equal(fixed[0], correct)
    assert fixed[1, 0, 0] / fixed[1, 1, 1] * own == pytest.approx(1.0)  # square at its own size


def test_focal_ratio_is_the_median_over_views_and_axes():
    from lumos3d_cli.geometry.field_of_view import focal_ratio

    predicted = torch.stack([_intrinsics(265.0, 265.0, (224, 168))] * 3)
    measured = torch.stack([_intrinsics(843.0, 843.0, (224, 168)), _intrinsics(800.0, 800.0, (224, 168)),
                            _intrinsics(265.0, 265.0, (224, 168))])
    assert focal_ratio(measured, predicted) == pytest.approx(800.0 / 265.0)
    assert focal_ratio(predicted, predicted) == 1.0


def test_the_fallback_lens_lands_on_a_stretched_photos_own_longer_side():
    """A portrait photo stretched to a landscape working size whose field of view failed: the
    fallback's 60 degrees went across it (its shorter side), 91.5 down."""
    size = (512, 288)
    own = (288 / 512) / (512 / 288)
    zero = (size[0] / 2) / math.tan(MIN_FOV / 2)
    fixed, replaced = plausible_intrinsics(_intrinsics(zero, zero, size)[None], size, torch.tensor([own]))
    assert replaced.tolist() == [True]
    down = math.degrees(2 * math.atan(size[1] / 2 / fixed[0, 1, 1].item()))
    assert down == pytest.approx(FALLBACK_FOV_DEGREES)  # the photo's longer side: its height
    assert fixed[0, 0, 0] / fixed[0, 1, 1] * own == pytest.approx(1.0)
