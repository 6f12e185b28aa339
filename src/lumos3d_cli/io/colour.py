"""sRGB <-> linear conversions, exact to IEC 61966-2-1, and the grey levels of RGB.

The only place where the sRGB transfer function and the luminance weights live. Works on numpy
arrays and torch tensors alike (any shape), returns the input's type and dtype.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, TypeVar

import numpy as np

from lumos3d_cli.tensors import loaded_torch

if TYPE_CHECKING:
    import torch

Array = TypeVar("Array", np.ndarray, "torch.Tensor")

# IEC 61966-2-1 constants.
_SRGB_DECODE_KNEE = 0.04045  # encoded value where the linear segment ends
_SRGB_ENCODE_KNEE = 0.0031308  # linear value where the linear segment ends
_SRGB_SLOPE = 12.92
_SRGB_GAMMA = 2.4
_SRGB_OFFSET = 0.055

# Rec. 709 / sRGB luminance of linear RGB.
LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)
# Rec. 601 luma of encoded RGB: OpenCV's RGB -> grey (and the start of its Lab conversion).
LUMA_WEIGHTS = (0.299, 0.587, 0.114)


def srgb_to_linear(encoded: Array) -> Array:
    """Decode sRGB values in [0, 1] to linear light. Values outside [0, 1] follow the same curve
    (negative values stay on the linear segment)."""
    torch = loaded_torch(encoded)
    if torch is not None:
        # Clamp inside the power branch so that its gradient stays finite where it is masked out.
        curve = ((encoded.clamp_min(_SRGB_DECODE_KNEE) + _SRGB_OFFSET) / (1 + _SRGB_OFFSET)) ** _SRGB_GAMMA
        return torch.where(encoded <= _SRGB_DECODE_KNEE, encoded / _SRGB_SLOPE, curve)
    encoded = np.asarray(encoded)
    curve = ((np.maximum(encoded, _SRGB_DECODE_KNEE) + _SRGB_OFFSET) / (1 + _SRGB_OFFSET)) ** _SRGB_GAMMA
    return np.where(encoded <= _SRGB_DECODE_KNEE, encoded / _SRGB_SLOPE, curve).astype(encoded.dtype, copy=False)


def linear_to_srgb(linear: Array) -> Array:
    """Encode linear light to sRGB. Inputs above 1 follow the curve (callers clip when they need
    [0, 1]); negative inputs stay on the linear segment."""
    torch = loaded_torch(linear)
    if torch is not None:
        curve = (1 + _SRGB_OFFSET) * linear.clamp_min(_SRGB_ENCODE_KNEE) ** (1 / _SRGB_GAMMA) - _SRGB_OFFSET
        return torch.where(linear <= _SRGB_ENCODE_KNEE, linear * _SRGB_SLOPE, curve)
    linear = np.asarray(linear)
    curve = (1 + _SRGB_OFFSET) * np.maximum(linear, _SRGB_ENCODE_KNEE) ** (1 / _SRGB_GAMMA) - _SRGB_OFFSET
    return np.where(linear <= _SRGB_ENCODE_KNEE, linear * _SRGB_SLOPE, curve).astype(linear.dtype, copy=False)


def _weighted_channels(images: Array, weights: tuple[float, float, float]) -> Array:
    """[..., 3, H, W] -> [..., 1, H, W]: the channels' weighted sum."""
    torch = loaded_torch(images)
    if torch is not None:
        kernel = torch.tensor(weights, dtype=images.dtype, device=images.device).reshape(3, 1, 1)
        return (images * kernel).sum(dim=-3, keepdim=True)
    images = np.asarray(images)
    kernel = np.asarray(weights, dtype=images.dtype).reshape(3, 1, 1)
    return (images * kernel).sum(axis=-3, keepdims=True)


def luminance(linear: Array) -> Array:
    """[..., 3, H, W] linear RGB -> [..., 1, H, W] Rec. 709 luminance."""
    return _weighted_channels(linear, LUMINANCE_WEIGHTS)


def luma(encoded: Array) -> Array:
    """[..., 3, H, W] encoded (sRGB) RGB -> [..., 1, H, W] Rec. 601 luma, OpenCV's grey."""
    return _weighted_channels(encoded, LUMA_WEIGHTS)
