import math

import numpy as np
import torch

from lumos3d_cli.geometry.vector_angles import angle_between


def test_angles_match_numpy_and_stay_exact_at_0_and_180_degrees():
    generator = torch.Generator().manual_seed(0)
    a = torch.randn(50, 3, generator=generator, dtype=torch.float64)
    b = torch.randn(50, 3, generator=generator, dtype=torch.float64)
    cosine = np.einsum("ij,ij->i", a.numpy(), b.numpy()) / (np.linalg.norm(a.numpy(), axis=1) * np.linalg.norm(b.numpy(), axis=1))
    assert np.allclose(angle_between(a, b).numpy(), np.degrees(np.arccos(cosine)), atol=1e-9)
    # a tiny angle, where arccos of a cosine rounded to 1 would give 0 or lose most digits
    tiny = torch.tensor([[1.0, 1e-9, 0.0]], dtype=torch.float64)
    x = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)
    assert math.isclose(float(angle_between(x, tiny)), math.degrees(1e-9), rel_tol=1e-6)
    assert float(angle_between(x, -x)) == 180.0 and float(angle_between(x, 3 * x)) == 0.0


def test_angles_broadcast_one_vector_against_many():
    rows = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)[:, None, :]  # [1, 1, 3]
    many = torch.tensor([[[0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]], dtype=torch.float64)  # [1, 3, 3]
    assert torch.allclose(angle_between(rows, many), torch.tensor([[90.0, 45.0, 180.0]], dtype=torch.float64))
