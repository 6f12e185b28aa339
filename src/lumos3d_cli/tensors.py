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
    """The torch module when `values` is a torch.Tensor (torch is then already imported), else None.
    While another thread is still importing torch, the module exists without its `Tensor` class:
    no value can be a tensor yet."""
    torch = sys.modules.get("torch")
    tensor_class = getattr(torch, "Tensor", None)
    return torch if tensor_class is not None and isinstance(values, tensor_class) else None
