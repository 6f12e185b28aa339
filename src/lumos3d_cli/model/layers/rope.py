"""2D rotary position embedding (RoPE) over patch rows and columns, as in VGGT.

The head dimension D is split in two halves: the first rotates with the token's row, the second
with its column. Within each half of size d, feature i pairs with feature i + d/2 and turns by
angle `position * frequency ** (-2i / d)` (the "rotate half" convention).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


def patch_positions(grid_height: int, grid_width: int, num_special: int, device=None) -> torch.Tensor:
    """(row, column) of every token of one frame: [num_special + h*w, 2] int64.

    Patches are numbered row-major starting at 1; the special (camera and register) tokens sit at
    (0, 0), where the rotation is the identity, so they carry no position.
    """
    rows = torch.arange(grid_height, device=device).repeat_interleave(grid_width)
    columns = torch.arange(grid_width, device=device).repeat(grid_height)
    patches = torch.stack((rows, columns), dim=1) + 1
    special = torch.zeros(num_special, 2, dtype=patches.dtype, device=device)
    return torch.cat((special, patches))


def _angle_table(half_dim: int, max_position: int, frequency: float, device) -> torch.Tensor:
    """[max_position, half_dim] rotation angles for one axis (float32)."""
    exponents = torch.arange(0, half_dim, 2, device=device, dtype=torch.float32) / half_dim
    inverse_frequency = 1.0 / frequency**exponents  # [half_dim / 2]
    positions = torch.arange(max_position, device=device, dtype=torch.float32)
    angles = positions[:, None] * inverse_frequency[None, :]
    return torch.cat((angles, angles), dim=-1)


@dataclass
class RotaryTables:
    """cos and sin per token and head feature: [N, D] each (float32)."""

    cos: torch.Tensor
    sin: torch.Tensor

    @staticmethod
    def build(positions: torch.Tensor, head_dim: int, frequency: float, max_position: int) -> RotaryTables:
        """Tables for `positions` [N, 2] (row, column), all below `max_position` (passed in, not
        read from the tensor, so that shape-only devices work), and `head_dim` divisible by 4."""
        half = head_dim // 2
        table = _angle_table(half, max_position, frequency, positions.device)
        angles = torch.cat((table[positions[:, 0]], table[positions[:, 1]]), dim=-1)  # [N, D]
        return RotaryTables(angles.cos(), angles.sin())

    def repeat(self, times: int) -> RotaryTables:
        """Tables for `times` frames laid one after another (global attention)."""
        return RotaryTables(self.cos.repeat(times, 1), self.sin.repeat(times, 1))

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        """Rotate queries or keys x [B, heads, N, D]."""
        quarters = x.unflatten(-1, (2, 2, x.shape[-1] // 4))  # [..., axis, pair half, d/2]
        rotated = torch.stack((-quarters[..., 1, :], quarters[..., 0, :]), dim=-2).flatten(-3)
        return x * self.cos.to(x.dtype) + rotated * self.sin.to(x.dtype)
