"""Clipped input invents no colour (model/appearance/clipped_highlights.py): a white wall clipped
in the photo restores neutral through an operator whose channels differ, unclipped pixels keep the
operator's colour, the identity stays the identity, and the weight has no seam."""

import cv2
import numpy as np
import torch

from lumos3d_cli.io.colour import linear_to_srgb, srgb_to_linear
from lumos3d_cli.model.appearance.clipped_highlights import (
    HIGHLIGHT_FULL,
    HIGHLIGHT_START,
    clipping_weight,
    keep_input_chromaticity,
)
from lumos3d_cli.model.appearance.curve import apply_curve
from lumos3d_cli.model.appearance.operator import AppearanceOperator

# CIELAB chroma below which a surface reads as neutral grey: about one just-noticeable
# difference (Delta E 2.3, Sharma 2003) from the grey axis.
NEUTRAL_CHROMA = 2.3


def _chroma(srgb: torch.Tensor) -> np.ndarray:
    """[3, H, W] sRGB -> [H, W] CIELAB a*b* radius (OpenCV, D65)."""
    lab = cv2.cvtColor(np.ascontiguousarray(srgb.permute(1, 2, 0).numpy().astype(np.float32)), cv2.COLOR_RGB2Lab)
    return np.hypot(lab[..., 1], lab[..., 2])


def _tinting_operator() -> AppearanceOperator:
    """Channels ending at different heights (red lifted, blue lowered) and a matrix with a cast:
    what over-exposure operators look like at the top of their range."""
    slopes = torch.ones(1, 3, 15)
    slopes[0, 0] *= 1.1
    slopes[0, 2] *= 0.8
    matrix = torch.eye(3)[None] + torch.tensor([[[0.05, 0.0, 0.0], [0.0, 0.0, 0.0], [0.03, 0.0, -0.05]]])
    return AppearanceOperator(slopes, matrix)


def test_a_clipped_white_wall_restores_neutral_and_colours_below_it_keep_the_operators_tint():
    photo = torch.ones(1, 1, 3, 8, 16)  # a clipped wall...
    photo[..., 8:] = torch.tensor([0.35, 0.5, 0.45]).reshape(3, 1, 1)  # ...beside an unclipped cyan-ish sofa
    operator = _tinting_operator()
    restored = operator.apply(photo)[0, 0]
    assert _chroma(restored[:, :, :8]).max() < NEUTRAL_CHROMA
    # below HIGHLIGHT_START the operator alone: matrix, then curve
    linear = srgb_to_linear(photo)
    mixed = torch.einsum("ij,bvjhw->bvihw", operator.matrix[0], linear).clamp_min(0)
    alone = linear_to_srgb(apply_curve(mixed, operator.curve_slopes, operator.knots).clamp(0, 1))[0, 0]
    torch.testing.assert_close(restored[:, :, 8:], alone[:, :, 8:])
    assert _chroma(restored[:, :, 8:]).mean() > 5  # the tint is the operator's to give there


def test_the_identity_operator_stays_the_identity_in_clipped_areas():
    photo = torch.rand(1, 2, 3, 12, 12)
    photo[0, 0, :, :4] = 1.0
    photo[0, 1, 0, 4:] = 0.99  # one channel near the top
    torch.testing.assert_close(AppearanceOperator.identity().apply(photo), photo, atol=2e-6, rtol=0)


def test_the_weight_rises_smoothly_from_start_to_full():
    levels = torch.linspace(0.7, 1.0, 301)
    weight = clipping_weight(srgb_to_linear(levels).reshape(1, 1, -1).expand(3, 1, -1))[0, 0]
    assert float(weight[levels < HIGHLIGHT_START].max()) == 0.0 and float(weight[levels >= HIGHLIGHT_FULL].min()) == 1.0
    assert float(weight.diff().min()) >= 0 and float(weight.diff().max()) < 0.05  # monotone, no jump


def test_black_and_clipped_pixels_give_finite_values_and_gradients():
    photo = torch.zeros(1, 1, 3, 4, 4)
    photo[..., :2] = 1.0
    output = torch.rand(1, 1, 3, 4, 4, dtype=torch.float64, requires_grad=True)
    kept = keep_input_chromaticity(srgb_to_linear(photo).double(), output)
    (gradient,) = torch.autograd.grad(kept.sum(), output)
    assert bool(torch.isfinite(kept).all()) and bool(torch.isfinite(gradient).all())


def test_a_grey_restoration_of_a_clipped_photo_has_a_finite_gradient():
    """A clipped white photo restored to exact grey has chromaticity offsets of exactly zero,
    where a bare square root's slope is infinite: training steps on such brackets came out NaN."""
    photo = torch.ones(1, 1, 3, 4, 4, dtype=torch.float64)
    output = torch.full((1, 1, 3, 4, 4), 0.7, dtype=torch.float64, requires_grad=True)
    kept = keep_input_chromaticity(photo, output)
    (gradient,) = torch.autograd.grad(kept.sum(), output)
    assert torch.allclose(kept, output) and bool(torch.isfinite(gradient).all())
