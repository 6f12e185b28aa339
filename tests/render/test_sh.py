import math

import numpy as np
import pytest
import torch
from numba import njit

from lumos3d_cli.render.kernels.sh import sh_basis, sh_basis_gradient
from lumos3d_cli.render.reference import sh_basis_reference


@njit
def _numba_basis(degree, directions):
    out = np.empty((directions.shape[0], (degree + 1) ** 2))
    for i in range(directions.shape[0]):
        sh_basis(degree, directions[i, 0], directions[i, 1], directions[i, 2], out[i])
    return out


@njit
def _numba_gradient(degree, directions, weights):
    out = np.empty((directions.shape[0], 3))
    for i in range(directions.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = sh_basis_gradient(degree, directions[i, 0], directions[i, 1], directions[i, 2], weights[i])
    return out


def _fibonacci_sphere(count: int) -> np.ndarray:
    index = np.arange(count) + 0.5
    polar = np.arccos(1 - 2 * index / count)
    azimuth = math.pi * (1 + 5**0.5) * index
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)


@pytest.mark.parametrize("degree", [0, 1, 2, 3, 4])
def test_basis_is_orthonormal_on_the_sphere(degree):
    """Independent check of every constant: the integral of Y_i Y_j over the sphere is delta_ij."""
    directions = _fibonacci_sphere(200_000)
    basis = _numba_basis(degree, directions)
    gram = basis.T @ basis * (4 * math.pi / len(directions))
    np.testing.assert_allclose(gram, np.eye(basis.shape[1]), atol=2e-4)


@pytest.mark.parametrize("degree", [0, 1, 2, 3, 4])
def test_numba_basis_and_gradient_match_the_torch_twin(degree):
    directions = torch.nn.functional.normalize(torch.randn(500, 3, dtype=torch.float64), dim=1)
    reference = sh_basis_reference(degree, directions)
    np.testing.assert_allclose(_numba_basis(degree, directions.numpy()), reference.numpy(), atol=1e-14)
    weights = torch.randn(500, (degree + 1) ** 2, dtype=torch.float64)
    free = directions.clone().requires_grad_(True)  # differentiate the polynomial, unconstrained
    if degree == 0:  # a constant: no dependence on the direction
        expected = torch.zeros_like(free)
    else:
        (expected,) = torch.autograd.grad((sh_basis_reference(degree, free) * weights).sum(), free)
    np.testing.assert_allclose(_numba_gradient(degree, directions.numpy(), weights.numpy()), expected.numpy(), atol=1e-12)
