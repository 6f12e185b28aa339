"""Bright input keeps its hue: clipped input invents no colour.

Near the top of the range a photo's channels clip one after another, and the operator's
per-channel curve and colour matrix — fitted mostly to the pixels below — rotate what hue is left
there: over-exposed LOM frames came out with pink smears on a tan floor (input hue 75 degrees,
reference 75, restored 62) and a clipped white wall tinted. In bright pixels the restoration keeps
its own luminance and saturation but takes the photo's hue (in linear chromaticity, the offset of
each channel from the luminance); its saturation is bounded by MAX_SATURATION_GAIN times the
photo's own plus NEUTRAL_SLACK, so a clipped white pixel, which holds no hue, stays white. The
weight rises from 0 where the darkest channel is at HIGHLIGHT_START to 1 at HIGHLIGHT_FULL (sRGB),
so the pixels below keep the operator's colour untouched and there is no seam.
"""

from __future__ import annotations

import torch

from lumos3d_cli.io.colour import linear_to_srgb, luminance, srgb_to_linear

# sRGB level of the darkest channel where the photo's hue starts to replace the operator's, and
# where it replaces it fully (the brightest 5 % of the range: only near-white pixels).
HIGHLIGHT_START = 0.80
HIGHLIGHT_FULL = 0.95
# How much more saturated than the photo a bright pixel may come out (over-exposure compresses
# saturation: buu's floor is 2.6x as saturated in the reference), and the saturation a pixel may
# have regardless (a just-visible tint: chromaticity offset 0.02 of the luminance).
MAX_SATURATION_GAIN = 8.0
NEUTRAL_SLACK = 0.03
_START_LINEAR = float(srgb_to_linear(torch.tensor(HIGHLIGHT_START, dtype=torch.float64)))


def clipping_weight(linear_input: torch.Tensor) -> torch.Tensor:
    """linear_input [..., 3, H, W] in [0, 1] -> [..., 1, H, W] in [0, 1]: how near the top the
    pixel's darkest channel is (0 below HIGHLIGHT_START, 1 from HIGHLIGHT_FULL, a smoothstep
    between)."""
    darkest = linear_input.clamp(0.0, 1.0).amin(dim=-3, keepdim=True)
    if not bool((darkest > _START_LINEAR).any()):
        # a dark photo (the common case): no pixel reaches the ramp, and the sRGB curve of a
        # whole photo is a power per pixel (a tenth of a low-light restore's operator time)
        return torch.zeros_like(darkest)
    darkest = linear_to_srgb(darkest)
    ramp = ((darkest - HIGHLIGHT_START) / (HIGHLIGHT_FULL - HIGHLIGHT_START)).clamp(0.0, 1.0)
    return ramp * ramp * (3.0 - 2.0 * ramp)


def _chromaticity(linear: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """[..., 3, H, W] -> (luminance [..., 1, H, W], each channel's offset from it relative to it)."""
    level = luminance(linear)
    return level, linear / level.clamp_min(1e-6) - 1.0


def _length(vectors: torch.Tensor) -> torch.Tensor:
    """[..., 3, H, W] -> [..., 1, H, W] Euclidean length over the channels (a sum of three squares:
    torch's norm over a strided middle dimension was 20 ms a view). The floor keeps the gradient
    finite at a grey pixel, whose offsets are exactly zero (the square root's slope is infinite
    there and 0 * inf is NaN): 1e-12 under the root is a length of 1e-6, far below NEUTRAL_SLACK."""
    return (vectors * vectors).sum(dim=-3, keepdim=True).clamp_min(1e-12).sqrt()


def keep_input_chromaticity(linear_input: torch.Tensor, linear_output: torch.Tensor) -> torch.Tensor:
    """linear_input, linear_output [..., 3, H, W] (the photo and the operator's restoration of it,
    linear light) -> the restoration where the photo's bright pixels take the photo's hue at the
    restoration's luminance and (bounded) saturation (module docstring). Differentiable in the
    output."""
    weight = clipping_weight(linear_input)
    if not bool((weight > 0).any()):  # a dark photo: nothing to do (the common case, and a cheap test)
        return linear_output
    _, source = _chromaticity(linear_input.clamp_min(0.0))
    level, restored = _chromaticity(linear_output.clamp_min(0.0))
    source_size = _length(source)
    size = torch.minimum(_length(restored), MAX_SATURATION_GAIN * source_size + NEUTRAL_SLACK)
    direction = source / source_size.clamp_min(1e-6)
    hue_kept = level * (1.0 + direction * size)
    return linear_output + weight * (hue_kept - linear_output)
