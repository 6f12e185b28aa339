"""Global statistics of the photos for the illumination head: per-channel histograms of log2
linear light.

Exposure is a shift of this histogram and clipping a spike in its last bin, so the head reads
the two things it must undo directly, whatever the aggregator's tokens kept of them.
"""

from __future__ import annotations

import torch

from lumos3d_cli.io.colour import srgb_to_linear

HISTOGRAM_BINS = 16
HISTOGRAM_STOPS = 12.0  # bins span log2 linear light in [-12, 0]; darker values fall in the first bin


def log_histograms(images: torch.Tensor, bins: int = HISTOGRAM_BINS, stops: float = HISTOGRAM_STOPS) -> torch.Tensor:
    """images [B, V, 3, H, W] sRGB in [0, 1] -> [B, V, 3, bins] float32, each row summing to 1.

    Not differentiable (the photos are inputs). Black pixels fall in the first bin, saturated
    ones in the last, so black and saturated frames give finite one-hot rows.
    """
    batch, views, channels = images.shape[:3]
    with torch.autocast(images.device.type, enabled=False):
        linear = srgb_to_linear(images.detach().float().clamp(0.0, 1.0)).reshape(batch, views, channels, -1)
        position = (torch.log2(linear.clamp_min(2.0**-stops)) + stops) / stops  # [0, 1]
        index = (position * bins).long().clamp(0, bins - 1)
        counts = torch.zeros(batch, views, channels, bins, device=images.device)
        counts.scatter_add_(-1, index, torch.ones_like(linear))
        return counts / linear.shape[-1]
