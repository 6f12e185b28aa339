"""The angle between 3D vectors, accurate at every angle."""

from __future__ import annotations

import torch


def angle_between(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Angle in degrees between vectors [..., 3] (broadcast), from atan2 of the cross and dot
    products: accurate near 0 and 180 degrees, where arccos of the cosine is not."""
    a, b = torch.broadcast_tensors(a, b)
    cross = torch.linalg.cross(a, b).norm(dim=-1)
    dot = (a * b).sum(dim=-1)
    return torch.rad2deg(torch.atan2(cross, dot))
