"""A DINOv2-style vision transformer with register tokens, used as VGGT's patch embedding."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from lumos3d_cli.model.layers.block import Block, run_block
from lumos3d_cli.model.layers.patch_embed import ConvPatchEmbed


class DinoVisionTransformer(nn.Module):
    """Patch conv, [cls, registers, patches] tokens, `depth` blocks, final LayerNorm.

    The learned position embedding covers a square grid of (image_size / patch_size)^2 patches
    plus the cls token and is resampled (bicubic, antialiased, as DINOv2/VGGT do) for other
    grids. Registers get no position embedding. Returns only the normalised patch tokens.
    """

    def __init__(
        self, image_size: int, patch_size: int, embed_dim: int, depth: int, num_heads: int,
        mlp_ratio: float, num_register_tokens: int,
    ):
        super().__init__()
        self.patch_size = patch_size
        self.num_register_tokens = num_register_tokens
        grid = image_size // patch_size
        self.patch_embed = ConvPatchEmbed(patch_size, embed_dim)
        self.cls_token = nn.Parameter(torch.zeros(1, 1, embed_dim))
        self.pos_embed = nn.Parameter(torch.zeros(1, 1 + grid * grid, embed_dim))
        self.register_tokens = nn.Parameter(torch.zeros(1, num_register_tokens, embed_dim))
        # DINOv2's masked-image-modelling token: unused here, kept so that checkpoints load strictly.
        self.mask_token = nn.Parameter(torch.zeros(1, embed_dim), requires_grad=False)
        self.blocks = nn.ModuleList(
            Block(embed_dim, num_heads, mlp_ratio, layer_scale_init=1.0, norm_eps=1e-6) for _ in range(depth)
        )
        self.norm = nn.LayerNorm(embed_dim, eps=1e-6)
        self.gradient_checkpointing = False
        nn.init.trunc_normal_(self.pos_embed, std=0.02)
        # normal(0, 1e-6), drawn by trunc_normal_ (bounds at 2e6 sigma): `normal_` on the meta device,
        # where `load_model` builds the network, would first load PyTorch's Python meta kernels (1 s).
        nn.init.trunc_normal_(self.cls_token, std=1e-6)
        nn.init.trunc_normal_(self.register_tokens, std=1e-6)

    def position_embedding(self, grid_height: int, grid_width: int, dtype: torch.dtype) -> torch.Tensor:
        """[1, 1 + h*w, C] embedding of the cls token and an h x w patch grid."""
        stored = self.pos_embed.shape[1] - 1
        side = math.isqrt(stored)
        if grid_height == grid_width == side:
            return self.pos_embed
        pos_embed = self.pos_embed.float()
        patches = pos_embed[:, 1:].reshape(1, side, side, -1).permute(0, 3, 1, 2)
        patches = F.interpolate(patches, size=(grid_height, grid_width), mode="bicubic", antialias=True)
        patches = patches.permute(0, 2, 3, 1).reshape(1, grid_height * grid_width, -1)
        return torch.cat((pos_embed[:, :1], patches), dim=1).to(dtype)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """[N, 3, H, W] normalised images -> [N, h*w, C] normalised patch tokens."""
        grid_height, grid_width = images.shape[-2] // self.patch_size, images.shape[-1] // self.patch_size
        x = self.patch_embed(images)
        x = torch.cat((self.cls_token.expand(x.shape[0], -1, -1), x), dim=1)
        x = x + self.position_embedding(grid_height, grid_width, x.dtype)
        x = torch.cat((x[:, :1], self.register_tokens.expand(x.shape[0], -1, -1), x[:, 1:]), dim=1)
        for block in self.blocks:
            x = run_block(block, x, checkpoint=self.gradient_checkpointing)
        return self.norm(x)[:, 1 + self.num_register_tokens :]
