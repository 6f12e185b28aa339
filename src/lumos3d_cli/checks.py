"""Guards that keep non-finite values, and images outside [0, 1], from passing silently."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from lumos3d_cli.errors import InputError, NonFiniteError
from lumos3d_cli.tensors import loaded_torch

if TYPE_CHECKING:
    import torch


def count_non_finite(values: np.ndarray | torch.Tensor) -> int:
    """Number of NaN or Inf entries."""
    torch = loaded_torch(values)
    if torch is not None:
        return int((~torch.isfinite(values)).sum().item()) if values.is_floating_point() else 0
    values = np.asarray(values)
    return int((~np.isfinite(values)).sum()) if np.issubdtype(values.dtype, np.floating) else 0


def _sum_is_finite(values: np.ndarray | torch.Tensor) -> bool:
    """Fast check: NaN and Inf propagate through a sum, so a finite sum means finite values
    (a non-finite sum can also come from overflow; the exact count decides then). The sum runs in
    the values' own precision, at least float32: a float64 sum of float32 values was 6x slower
    (48 ms for a scene's 10M SH coefficients, checked at every render), and an overflow only
    sends the check to the exact count."""
    torch = loaded_torch(values)
    if torch is not None:
        if not values.is_floating_point():
            return True
        wide = torch.promote_types(values.dtype, torch.float32)
        return bool(torch.isfinite(values.detach().sum(dtype=wide)))
    values = np.asarray(values)
    if not np.issubdtype(values.dtype, np.floating):
        return True
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is the exact count's to judge
        total = values.sum(dtype=np.promote_types(values.dtype, np.float32))
    return bool(np.isfinite(total))


def require_finite(name: str, values: np.ndarray | torch.Tensor, hint: str = "") -> None:
    """Raise NonFiniteError naming `name` and the count when `values` holds NaN or Inf."""
    if _sum_is_finite(values):
        return
    bad = count_non_finite(values)
    if bad:
        total = values.numel() if loaded_torch(values) is not None else np.asarray(values).size
        message = f"{name}: {bad} of {total} values are NaN or Inf"
        raise NonFiniteError(f"{message}; {hint}" if hint else message)


# How far outside [0, 1] an image may stray (rounding in a colour conversion) before it is taken
# for another range: 8-bit codes not divided by 255, or a normalised -1..1 or mean-subtracted batch.
UNIT_RANGE_TOLERANCE = 1e-3


def require_unit_range(name: str, images: torch.Tensor) -> None:
    """InputError naming `name` and the range found unless `images` (non-empty, finite) lie in
    [0, 1]: the network clamps what it is given, so 0..255 input became a white frame silently."""
    low, high = float(images.min()), float(images.max())
    if low < -UNIT_RANGE_TOLERANCE or high > 1 + UNIT_RANGE_TOLERANCE:
        scale = " (8-bit codes: divide by 255)" if high > 2 else ""
        raise InputError(f"{name}: values from {low:.4g} to {high:.4g}; give sRGB in [0, 1]{scale}")
