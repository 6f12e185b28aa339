import torch

from lumos3d_cli.rotations import DEGENERATE_QUATERNION_NORM, quaternion_to_matrix, unit_quaternions
from lumos3d_cli.viewer.splats import covariances


def test_unit_quaternions_normalise_and_take_vanished_ones_as_the_identity():
    quats = torch.tensor([[2.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [0.0, 3.0, 4.0, 0.0],
                          [DEGENERATE_QUATERNION_NORM / 2, 0.0, 0.0, 0.0]], dtype=torch.float64, requires_grad=True)
    unit = unit_quaternions(quats)
    expected = torch.tensor([[1.0, 0, 0, 0], [1.0, 0, 0, 0], [0.0, 0.6, 0.8, 0], [1.0, 0, 0, 0]], dtype=torch.float64)
    torch.testing.assert_close(unit, expected)
    unit.sum().backward()
    assert bool(torch.isfinite(quats.grad).all())


def test_a_zero_quaternion_is_the_identity_rotation_everywhere_it_is_read():
    """The viewer's covariances once divided by the zero norm and sent NaN to the browser."""
    quats = torch.tensor([[0.0, 0.0, 0.0, 0.0], [0.5, 0.5, 0.5, 0.5]], dtype=torch.float64)
    torch.testing.assert_close(quaternion_to_matrix(quats)[0], torch.eye(3, dtype=torch.float64))
    sigma = covariances(quats, torch.tensor([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]], dtype=torch.float64))
    torch.testing.assert_close(sigma[0], torch.diag(torch.tensor([1.0, 4.0, 9.0], dtype=torch.float64)))
    assert bool(torch.isfinite(sigma).all())


def test_a_huge_float32_quaternion_is_the_rotation_it_points_at():
    """Squaring 1e20 overflows float32: the norm is taken after dividing by the largest component."""
    huge = torch.tensor([[1e20, 1e20, 1e20, 1e20], [3e30, 0.0, 4e30, 0.0]], dtype=torch.float32)
    torch.testing.assert_close(unit_quaternions(huge), torch.tensor([[0.5, 0.5, 0.5, 0.5], [0.6, 0.0, 0.8, 0.0]]))
    torch.testing.assert_close(quaternion_to_matrix(huge[:1]), quaternion_to_matrix(torch.full((1, 4), 0.5)))
