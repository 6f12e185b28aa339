"""Rotation matrices <-> unit quaternions (scalar-first wxyz), batched torch.

Other orders (VGGT's xyzw pose encoding) reorder at their boundary.
"""

from __future__ import annotations

import torch


# Quaternions shorter than this carry no direction: they count as the identity rotation (the
# rasterizer's kernels read them so too, render/kernels/projection.py).
DEGENERATE_QUATERNION_NORM = 1e-12


def unit_quaternions(quats: torch.Tensor) -> torch.Tensor:
    """[..., 4] wxyz -> unit quaternions [..., 4]; (near-)zero ones become the identity (1, 0, 0, 0).
    Divided by the largest component first, so that no square overflows (a float32 quaternion of
    1e20 is a rotation, not infinity). Differentiable where the norm is above
    DEGENERATE_QUATERNION_NORM."""
    peak = quats.detach().abs().amax(dim=-1, keepdim=True)
    scaled = quats / peak.clamp_min(torch.finfo(quats.dtype).tiny)
    scaled_norms = scaled.norm(dim=-1, keepdim=True)  # in [1, 2] where the peak is not 0
    identity = torch.zeros_like(quats)
    identity[..., 0] = 1.0
    degenerate = (peak == 0) | (peak < DEGENERATE_QUATERNION_NORM / scaled_norms.clamp_min(1.0))
    return torch.where(degenerate, identity, scaled / scaled_norms.clamp_min(1.0))


def quaternion_to_matrix(quats: torch.Tensor) -> torch.Tensor:
    """[..., 4] wxyz (normalised here, `unit_quaternions`) -> [..., 3, 3] rotation."""
    quats = unit_quaternions(quats)
    w, x, y, z = quats.unbind(-1)
    rows = (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )
    return torch.stack(rows, dim=-1).reshape(quats.shape[:-1] + (3, 3))


def matrix_to_quaternion(matrices: torch.Tensor) -> torch.Tensor:
    """[..., 3, 3] rotation -> [..., 4] wxyz with w >= 0.

    Uses the largest of the four candidate denominators (Shepperd's method) so that it stays
    accurate for 180-degree rotations.
    """
    m = matrices
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    # 4*w^2, 4*x^2, 4*y^2, 4*z^2 (clamped: rounding can push them slightly below 0)
    squares = torch.stack(
        (1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22), dim=-1
    ).clamp_min(0)
    candidates = torch.stack(
        (
            torch.stack((squares[..., 0], m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]), -1),
            torch.stack((m[..., 2, 1] - m[..., 1, 2], squares[..., 1], m[..., 1, 0] + m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0]), -1),
            torch.stack((m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] + m[..., 0, 1], squares[..., 2], m[..., 2, 1] + m[..., 1, 2]), -1),
            torch.stack((m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 2, 1] + m[..., 1, 2], squares[..., 3]), -1),
        ),
        dim=-2,
    )  # [..., 4 candidates, 4 components]; candidate i = 4*q_i*q, accurate when q_i is largest
    best = squares.argmax(dim=-1, keepdim=True)
    chosen = torch.gather(candidates, -2, best[..., None].expand(best.shape[:-1] + (1, 4))).squeeze(-2)
    quats = chosen / chosen.norm(dim=-1, keepdim=True)
    return torch.where(quats[..., :1] < 0, -quats, quats)
