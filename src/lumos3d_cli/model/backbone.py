"""The VGGT aggregator: patch tokens plus per-frame camera/register tokens, refined by
alternating frame-wise and global attention.

Module and parameter names equal VGGT's (`aggregator.*` in its checkpoint), so official weights
load without renaming.
"""

from __future__ import annotations

from collections.abc import Iterable

import torch
from torch import nn

from lumos3d_cli.model.architectures import Architecture
from lumos3d_cli.model.layers.block import Block, run_block
from lumos3d_cli.model.layers.patch_embed import ConvPatchEmbed
from lumos3d_cli.model.layers.rope import RotaryTables, patch_positions
from lumos3d_cli.model.layers.vision_transformer import DinoVisionTransformer

# ImageNet statistics: the DINOv2 patch embed was trained on images normalised this way.
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def _first_and_other_frames(token: torch.Tensor, batch: int, frames: int) -> torch.Tensor:
    """[1, 2, X, C] -> [B*S, X, C]: slot 0 for each first frame, slot 1 for every other frame.

    The first frame defines the world coordinate frame, so it gets its own learned tokens.
    """
    first = token[:, :1].expand(batch, 1, *token.shape[2:])
    others = token[:, 1:].expand(batch, frames - 1, *token.shape[2:])
    return torch.cat((first, others), dim=1).reshape(batch * frames, *token.shape[2:])


class Aggregator(nn.Module):
    """Images [B, S, 3, H, W] in [0, 1] -> tokens of selected layers, each [B, S, P, 2C].

    P = 1 camera token + R register tokens + (H/p)(W/p) patch tokens. Layer i's output is the
    frame block i output and the global block i output concatenated on channels.
    """

    def __init__(self, architecture: Architecture):
        super().__init__()
        self.patch_size = architecture.patch_size
        self.num_heads = architecture.num_heads
        self.rope_frequency = architecture.rope_frequency
        self.patch_start_index = architecture.patch_start_index
        dim = architecture.embed_dim
        if architecture.patch_embed.kind == "dinov2":
            self.patch_embed = DinoVisionTransformer(
                architecture.image_size, architecture.patch_size, dim, architecture.patch_embed.depth, architecture.patch_embed.num_heads,
                architecture.patch_embed.mlp_ratio, architecture.num_register_tokens,
            )
        else:
            self.patch_embed = ConvPatchEmbed(architecture.patch_size, dim)

        def blocks() -> nn.ModuleList:
            return nn.ModuleList(
                Block(dim, architecture.num_heads, architecture.mlp_ratio, architecture.layer_scale_init, qk_norm=True)
                for _ in range(architecture.depth)
            )

        self.frame_blocks = blocks()
        self.global_blocks = blocks()
        # normal(0, 1e-6) as VGGT initialises them, drawn in place: `randn` and `*` on the meta device
        # (where `load_model` builds the network) would first load PyTorch's Python meta kernels, 1 s.
        self.camera_token = nn.Parameter(nn.init.trunc_normal_(torch.empty(1, 2, 1, dim), std=1e-6))
        self.register_token = nn.Parameter(nn.init.trunc_normal_(torch.empty(1, 2, architecture.num_register_tokens, dim), std=1e-6))
        self.gradient_checkpointing = False

    def set_gradient_checkpointing(self, enabled: bool) -> None:
        self.gradient_checkpointing = enabled
        if isinstance(self.patch_embed, DinoVisionTransformer):
            self.patch_embed.gradient_checkpointing = enabled

    def forward(self, images: torch.Tensor, layers: Iterable[int]) -> dict[int, torch.Tensor]:
        """images [B, S, 3, H, W] in [0, 1], H and W multiples of the patch size ->
        {layer index: [B, S, P, 2C]} for each requested layer."""
        batch, frames, _, height, width = images.shape
        wanted = set(layers)
        mean = torch.tensor(IMAGENET_MEAN, dtype=images.dtype, device=images.device).view(1, 1, 3, 1, 1)
        std = torch.tensor(IMAGENET_STD, dtype=images.dtype, device=images.device).view(1, 1, 3, 1, 1)
        normalised = ((images - mean) / std).reshape(batch * frames, 3, height, width)
        patches = self.patch_embed(normalised)  # [B*S, h*w, C]
        tokens = torch.cat(
            (
                _first_and_other_frames(self.camera_token, batch, frames),
                _first_and_other_frames(self.register_token, batch, frames),
                patches,
            ),
            dim=1,
        )
        tokens_per_frame, channels = tokens.shape[1], tokens.shape[2]
        grid_h, grid_w = height // self.patch_size, width // self.patch_size
        positions = patch_positions(grid_h, grid_w, self.patch_start_index, images.device)
        frame_rope = RotaryTables.build(positions, channels // self.num_heads, self.rope_frequency, max(grid_h, grid_w) + 1)
        global_rope = frame_rope.repeat(frames)

        outputs: dict[int, torch.Tensor] = {}
        for index, (frame_block, global_block) in enumerate(zip(self.frame_blocks, self.global_blocks)):
            tokens = run_block(frame_block, tokens.reshape(batch * frames, tokens_per_frame, channels), frame_rope, self.gradient_checkpointing)
            frame_out = tokens.reshape(batch, frames, tokens_per_frame, channels)
            tokens = run_block(global_block, tokens.reshape(batch, frames * tokens_per_frame, channels), global_rope, self.gradient_checkpointing)
            if index in wanted:
                global_out = tokens.reshape(batch, frames, tokens_per_frame, channels)
                outputs[index] = torch.cat((frame_out, global_out), dim=-1)
        return outputs
