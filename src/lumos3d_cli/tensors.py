"""Telling a torch tensor from a numpy array without importing torch.

Photos are read, checked and brightened for structure-from-motion before torch is imported
(`pipeline.early_registration`: importing torch is 1-1.5 s of a restore's start-up), by code that
also takes tensors later on. A value can only be a tensor once torch has been imported, so the
question needs no import of its own.
"""

from __future__ import annotations

import sys
from types import ModuleType


def loaded_torch(values: object) -> ModuleType | None:
    """The torch module when `values` is a torch.Tensor (torch is then already imported), else None."""
    torch = sys.modules.get("torch")
    return torch if torch is not None and isinstance(values, torch.Tensor) else None
