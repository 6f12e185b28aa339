"""Appearance diagnostics of restored images against references (issue 35): how far the overall
brightness is off, in stops, and how saturated the colours are, as CIE Lab chroma.

- brightness error: log2 of the mean linear-light luminance (Rec. 709 weights, the sRGB transfer
  function of io.colour) of the image over its reference's. Signed: -1 is one stop too dark
  (half the light), +0.5 half a stop too bright; 0 is the reference's exposure.
- chroma: the mean over pixels of the a*b* radius sqrt(a*^2 + b*^2) in CIE Lab (D65, the sRGB
  primaries; OpenCV's `cvtColor(COLOR_RGB2Lab)` on float32 sRGB in [0, 1]). 0 is grey; the
  reference's is the level a restoration should reach, so their ratio (image over reference)
  below 1 means washed-out colour.

Images are float sRGB in [0, 1], [..., 3, H, W], like eval.metrics.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch

from lumos3d_cli.io.colour import luminance, srgb_to_linear


def _flatten(images: torch.Tensor) -> torch.Tensor:
    if images.dim() < 3 or images.shape[-3] != 3:
        raise ValueError(f"expected images [..., 3, H, W], got {tuple(images.shape)}")
    return images.reshape(-1, *images.shape[-3:])


def mean_linear_luminance(images: torch.Tensor) -> torch.Tensor:
    """[..., 3, H, W] sRGB in [0, 1] -> [...] float64 mean Rec. 709 luminance in linear light."""
    linear = srgb_to_linear(_flatten(images).double().clamp(0.0, 1.0))
    return luminance(linear).mean(dim=(1, 2, 3)).reshape(images.shape[:-3])


def brightness_stops(images: torch.Tensor, references: torch.Tensor) -> torch.Tensor:
    """[..., 3, H, W] images and references -> [...] float64 log2(mean linear luminance of the
    image / of its reference): negative too dark, positive too bright. A black image scores
    -inf; a black reference +inf (or NaN when both are black)."""
    return torch.log2(mean_linear_luminance(images)) - torch.log2(mean_linear_luminance(references))


def mean_chroma(images: torch.Tensor) -> torch.Tensor:
    """[..., 3, H, W] sRGB in [0, 1] -> [...] float64 mean CIE Lab chroma (a*b* radius) per image."""
    flat = _flatten(images).clamp(0.0, 1.0)
    values = []
    for image in flat:
        pixels = np.ascontiguousarray(image.permute(1, 2, 0).numpy(), dtype=np.float32)
        lab = cv2.cvtColor(pixels, cv2.COLOR_RGB2Lab)
        values.append(float(np.hypot(lab[..., 1].astype(np.float64), lab[..., 2].astype(np.float64)).mean()))
    return torch.tensor(values, dtype=torch.float64).reshape(images.shape[:-3])


def appearance_stats(images: torch.Tensor, references: torch.Tensor) -> list[dict[str, float]]:
    """Per image of [N, 3, H, W] (or a sequence of [3, H, W], each the size of its reference):
    {stops, chroma, chroma_reference, chroma_ratio} (brightness_stops; mean_chroma of the image
    and of the reference; their ratio, NaN for a grey reference)."""
    if len(images) != len(references):
        raise ValueError(f"{len(images)} images for {len(references)} references")
    rows = []
    for image, reference in zip(images, references):
        chroma, reference_chroma = float(mean_chroma(image)), float(mean_chroma(reference))
        rows.append({
            "stops": float(brightness_stops(image, reference)),
            "chroma": chroma,
            "chroma_reference": reference_chroma,
            "chroma_ratio": chroma / reference_chroma if reference_chroma > 0 else math.nan,
        })
    return rows
