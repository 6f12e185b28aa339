"""The per-channel tone curve of the restoration operator: piecewise linear in linear light,
monotone by construction, identity at initialisation, slope bounded.

Knots: x_0 = 0, then `CURVE_KNOTS - 1` knots log-spaced from 2^-CURVE_STOPS to 1, so every
segment above the first spans the same number of stops (0.8 with the defaults): dark pixels,
where low light puts nearly everything, get as many degrees of freedom as highlights. Each
segment's slope is MAX_GAIN ** tanh(raw), i.e. within [1/MAX_GAIN, MAX_GAIN] and strictly
positive, so the curve is strictly increasing for any raw parameters; raw = 0 gives slope 1
everywhere, the identity. A constant slope g is the pure gain x -> g x, so the family contains
the per-channel gain exactly. Inputs above 1 continue on the last segment (callers clip).
"""

from __future__ import annotations

import math

import torch

CURVE_KNOTS = 17  # 16 segments, hence 16 free slopes per channel
CURVE_STOPS = 12.0  # the lowest non-zero knot, 2^-12 in linear light, encodes below one 8-bit sRGB step
MAX_GAIN = 64.0  # 6 stops: more than the paper's darkest synthetic exposure (x0.05 = 4.3 stops) needs


def curve_knots(knots: int = CURVE_KNOTS, stops: float = CURVE_STOPS) -> torch.Tensor:
    """[knots] float32 knot positions in linear light: 0, then log-spaced from 2^-stops to 1."""
    if knots < 3:
        raise ValueError(f"a curve needs at least 3 knots, got {knots}")
    exponents = torch.linspace(-stops, 0.0, knots - 1, dtype=torch.float64)
    return torch.cat((torch.zeros(1, dtype=torch.float64), 2.0**exponents)).float()


def bound_slopes(raw: torch.Tensor, max_gain: float = MAX_GAIN) -> torch.Tensor:
    """[..., K-1] unbounded -> slopes in [1/max_gain, max_gain] (1 where raw = 0)."""
    return torch.exp(math.log(max_gain) * torch.tanh(raw))


def raw_for_slopes(slopes: torch.Tensor, max_gain: float = MAX_GAIN) -> torch.Tensor:
    """Inverse of `bound_slopes` for slopes strictly inside the bounds (initialising fits)."""
    limit = 1 - 1e-6
    return torch.atanh((torch.log(slopes) / math.log(max_gain)).clamp(-limit, limit))


def curve_values(slopes: torch.Tensor, knots: torch.Tensor) -> torch.Tensor:
    """slopes [..., K-1], knots [K] -> curve values at the knots [..., K] (0 at x = 0)."""
    widths = (knots[1:] - knots[:-1]).to(slopes)
    steps = torch.cumsum(slopes * widths, dim=-1)
    return torch.cat((torch.zeros_like(steps[..., :1]), steps), dim=-1)


def apply_curve(linear: torch.Tensor, slopes: torch.Tensor, knots: torch.Tensor) -> torch.Tensor:
    """linear [B, V, 3, H, W] (clamped at 0), slopes [B, 3, K-1] -> [B, V, 3, H, W].

    Scene b's channel c goes through curve (b, c). Float32 whatever the input dtype.
    """
    batch, views, channels, height, width = linear.shape
    x = linear.float().clamp_min(0.0).contiguous()
    knots = knots.to(x.device)
    slopes = slopes.float()
    # Segment i covers [knots[i], knots[i+1]); x >= 1 stays in the last segment (linear extension).
    segment = torch.bucketize(x, knots[1:-1], right=True).reshape(batch, views, channels, height * width)
    values = curve_values(slopes, knots)[:, None].expand(batch, views, channels, -1)  # [B, V, 3, K]
    slope_table = slopes[:, None].expand(batch, views, channels, -1)  # [B, V, 3, K-1]
    start = torch.gather(values, -1, segment)
    slope = torch.gather(slope_table, -1, segment)
    origin = knots[segment]
    out = start + slope * (x.reshape(batch, views, channels, -1) - origin)
    return out.reshape(batch, views, channels, height, width)
