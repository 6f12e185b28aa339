"""Camera head: the camera tokens -> pose encodings, refined iteratively (VGGT)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from lumos3d_cli.model.architectures import Architecture
from lumos3d_cli.model.layers.block import Block
from lumos3d_cli.model.layers.mlp import Mlp
from lumos3d_cli.model.pose_encoding import POSE_ENCODING_SIZE


def activate_pose(raw: torch.Tensor) -> torch.Tensor:
    """[..., 9] raw -> encoding: translation and quaternion unchanged, fields of view ReLU'd."""
    return torch.cat((raw[..., :7], F.relu(raw[..., 7:])), dim=-1)


class CameraHead(nn.Module):
    """Tokens of the last aggregator layer [B, S, P, 2C] -> one pose encoding [B, S, 9] per
    refinement iteration.

    Each iteration embeds the current (raw) estimate, turns it into adaLN shift/scale/gate that
    modulate the normalised camera tokens, runs a small transformer across the S frames and adds
    the predicted update. The estimate fed back is detached, so every iteration learns a
    one-step correction (as in VGGT); the distillation loss supervises all iterations.
    """

    def __init__(self, architecture: Architecture):
        super().__init__()
        dim = 2 * architecture.embed_dim
        self.iterations = architecture.camera_iterations
        self.trunk = nn.Sequential(
            *(Block(dim, architecture.camera_num_heads, architecture.mlp_ratio, architecture.layer_scale_init) for _ in range(architecture.camera_trunk_depth))
        )
        self.token_norm = nn.LayerNorm(dim)
        self.trunk_norm = nn.LayerNorm(dim)
        self.empty_pose_tokens = nn.Parameter(torch.zeros(1, 1, POSE_ENCODING_SIZE))
        self.embed_pose = nn.Linear(POSE_ENCODING_SIZE, dim)
        self.poseLN_modulation = nn.Sequential(nn.SiLU(), nn.Linear(dim, 3 * dim))
        self.adaln_norm = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        self.pose_branch = Mlp(dim, dim // 2, POSE_ENCODING_SIZE)

    def forward(self, tokens: torch.Tensor) -> list[torch.Tensor]:
        """tokens [B, S, P, 2C] -> list of `iterations` encodings [B, S, 9] (activated)."""
        camera_tokens = self.token_norm(tokens[:, :, 0])  # [B, S, 2C]
        batch, frames, _ = camera_tokens.shape
        normalised = self.adaln_norm(camera_tokens)
        estimate = None
        encodings = []
        for _ in range(self.iterations):
            previous = self.empty_pose_tokens.expand(batch, frames, -1) if estimate is None else estimate.detach()
            shift, scale, gate = self.poseLN_modulation(self.embed_pose(previous)).chunk(3, dim=-1)
            modulated = gate * (normalised * (1 + scale) + shift) + camera_tokens
            delta = self.pose_branch(self.trunk_norm(self.trunk(modulated)))
            estimate = delta if estimate is None else estimate + delta
            encodings.append(activate_pose(estimate))
        return encodings
