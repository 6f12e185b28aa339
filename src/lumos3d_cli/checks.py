"""Guards that keep non-finite values from escaping silently."""

from __future__ import annotations

import numpy as np
import torch

from lumos3d_cli.errors import NonFiniteError


def count_non_finite(values: np.ndarray | torch.Tensor) -> int:
    """Number of NaN or Inf entries."""
    if isinstance(values, torch.Tensor):
        return int((~torch.isfinite(values)).sum().item()) if values.is_floating_point() else 0
    values = np.asarray(values)
    return int((~np.isfinite(values)).sum()) if np.issubdtype(values.dtype, np.floating) else 0


def _sum_is_finite(values: np.ndarray | torch.Tensor) -> bool:
    """Fast check: NaN and Inf propagate through a sum, so a finite sum means finite values
    (a non-finite sum can also come from overflow; the exact count decides then)."""
    if isinstance(values, torch.Tensor):
        return not values.is_floating_point() or bool(torch.isfinite(values.detach().sum(dtype=torch.float64)))
    values = np.asarray(values)
    return not np.issubdtype(values.dtype, np.floating) or bool(np.isfinite(values.sum(dtype=np.float64)))


def require_finite(name: str, values: np.ndarray | torch.Tensor, hint: str = "") -> None:
    """Raise NonFiniteError naming `name` and the count when `values` holds NaN or Inf."""
    if _sum_is_finite(values):
        return
    bad = count_non_finite(values)
    if bad:
        total = values.numel() if isinstance(values, torch.Tensor) else np.asarray(values).size
        message = f"{name}: {bad} of {total} values are NaN or Inf"
        raise NonFiniteError(f"{message}; {hint}" if hint else message)
