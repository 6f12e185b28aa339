"""The per-view local correction: a coarse grid of log2 gains (lamps, vignetting, light falling
off across a room), bounded and smoothly upsampled to any image size.

The grid covers the whole frame, so one grid serves the network image and the full-resolution
photo alike (as long as the network image is the whole photo resized, not a crop).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

LOCAL_GRID_SIZE = 8  # cells per side
LOCAL_MAX_STOPS = 2.0  # gains within [1/4, 4]: local light differences, not the scene's exposure


def bound_log_gain(raw: torch.Tensor, max_stops: float = LOCAL_MAX_STOPS) -> torch.Tensor:
    """[..., g, g] unbounded -> log2 gains in (-max_stops, max_stops) (0 where raw = 0)."""
    return max_stops * torch.tanh(raw)


def upsample_log_gain(log_gain: torch.Tensor, height: int, width: int, max_stops: float = LOCAL_MAX_STOPS) -> torch.Tensor:
    """[N, C, g, g] log2 gains -> [N, C, height, width] float32, bicubic (continuous slope, so
    no seams at cell borders), clamped back to the bound that bicubic overshoot can cross."""
    if log_gain.shape[-2:] == (height, width):
        return log_gain.float()
    upsampled = F.interpolate(log_gain.float(), size=(height, width), mode="bicubic", align_corners=False)
    return upsampled.clamp(-max_stops, max_stops)
