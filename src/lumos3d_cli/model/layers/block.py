"""The pre-norm transformer block used everywhere in the network."""

from __future__ import annotations

import torch
from torch import nn

from lumos3d_cli.model.layers.attention import Attention
from lumos3d_cli.model.layers.layer_scale import LayerScale
from lumos3d_cli.model.layers.mlp import Mlp
from lumos3d_cli.model.layers.rope import RotaryTables


class Block(nn.Module):
    """x + ls1(attn(norm1(x))), then + ls2(mlp(norm2(x))).

    `norm_eps` is 1e-5 in the aggregator and camera head and 1e-6 in the DINOv2 patch embed,
    as in the checkpoints these blocks load.
    """

    def __init__(
        self,
        dim: int,
        num_heads: int,
        mlp_ratio: float = 4.0,
        layer_scale_init: float = 0.01,
        qk_norm: bool = False,
        norm_eps: float = 1e-5,
    ):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=norm_eps)
        self.attn = Attention(dim, num_heads, qk_norm=qk_norm)
        self.ls1 = LayerScale(dim, layer_scale_init)
        self.norm2 = nn.LayerNorm(dim, eps=norm_eps)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))
        self.ls2 = LayerScale(dim, layer_scale_init)

    def forward(self, x: torch.Tensor, rope: RotaryTables | None = None) -> torch.Tensor:
        """x [B, N, C] -> [B, N, C]."""
        x = x + self.ls1(self.attn(self.norm1(x), rope))
        return x + self.ls2(self.mlp(self.norm2(x)))


def run_block(block: nn.Module, x: torch.Tensor, rope: RotaryTables | None = None, checkpoint: bool = False) -> torch.Tensor:
    """`block(x, rope)`, recomputed in the backward pass instead of stored when `checkpoint` is
    set and gradients are being recorded (trades compute for activation memory in training)."""
    if checkpoint and torch.is_grad_enabled():
        return torch.utils.checkpoint.checkpoint(block, x, rope, use_reentrant=False)
    return block(x, rope)
