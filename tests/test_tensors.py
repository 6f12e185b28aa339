"""Telling tensors from arrays without importing torch (tensors.py), and the torch-free checks and
colour conversions built on it, also while another thread is still importing torch (the module
is then in sys.modules without its Tensor class)."""

import sys
import types

import numpy as np
import pytest
import torch

from lumos3d_cli.checks import count_non_finite, require_finite
from lumos3d_cli.errors import NonFiniteError
from lumos3d_cli.io.colour import linear_to_srgb, srgb_to_linear
from lumos3d_cli.tensors import loaded_torch


def test_tells_tensors_from_arrays():
    assert loaded_torch(torch.zeros(2)) is torch
    assert loaded_torch(np.zeros(2)) is None and loaded_torch([0.0]) is None


def test_numpy_checks_and_colours_while_torch_is_half_imported(monkeypatch):
    monkeypatch.setitem(sys.modules, "torch", types.ModuleType("torch"))  # no Tensor yet
    assert loaded_torch(np.ones(3)) is None
    require_finite("pixels", np.ones(3, np.float32))
    with pytest.raises(NonFiniteError, match="pixels: 1 of 3"):
        require_finite("pixels", np.array([1.0, np.nan, 0.0], np.float32))
    assert count_non_finite(np.array([np.inf, 0.0])) == 1
    np.testing.assert_allclose(srgb_to_linear(linear_to_srgb(np.linspace(0, 1, 5))), np.linspace(0, 1, 5), atol=1e-12)
