"""DPT dense heads: four aggregator layers -> a feature pyramid -> per-pixel predictions."""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import nn

from lumos3d_cli.model.architectures import Architecture
from lumos3d_cli.model.heads.fusion import FusionScratch
from lumos3d_cli.model.heads.uv_embedding import add_uv_embedding

# Frames decoded together; every operation is per frame, so this only bounds peak memory.
FRAMES_PER_CHUNK = 8
# Logits are clamped before exp() so that no input can overflow depth or confidence to Inf or
# underflow depth to 0; exp(+-40) ~ 2e17 / 4e-18 lie far outside any depth a trained network predicts.
MAX_LOG_VALUE = 40.0


class DPTHead(nn.Module):
    """The shared DPT trunk; `DepthHead` and `GaussianHead` add `scratch.output_conv2` and the
    full-resolution output step.

    For each of the four layers: LayerNorm of the patch tokens, 1x1 projection, UV embedding,
    resampling to 4x, 2x, 1x and 1/2x the patch grid; then coarse-to-fine fusion to
    [N, features/2, 8h, 8w].
    """

    def __init__(self, architecture: Architecture):
        super().__init__()
        dim = 2 * architecture.embed_dim
        channels = architecture.dpt_out_channels
        self.patch_size = architecture.patch_size
        self.patch_start_index = architecture.patch_start_index
        self.layers = tuple(architecture.intermediate_layers)
        self.norm = nn.LayerNorm(dim)
        self.projects = nn.ModuleList(nn.Conv2d(dim, c, kernel_size=1) for c in channels)
        self.resize_layers = nn.ModuleList(
            (
                nn.ConvTranspose2d(channels[0], channels[0], kernel_size=4, stride=4),
                nn.ConvTranspose2d(channels[1], channels[1], kernel_size=2, stride=2),
                nn.Identity(),
                nn.Conv2d(channels[3], channels[3], kernel_size=3, stride=2, padding=1),
            )
        )
        self.scratch = FusionScratch(channels, architecture.dpt_features)

    def fused_features(self, tokens: dict[int, torch.Tensor], frames: slice, image_hw: tuple[int, int]) -> torch.Tensor:
        """tokens {layer: [B, S, P, 2C]} -> [B*s, features/2, 8h, 8w] for the frames in `frames`."""
        height, width = image_hw
        grid_h, grid_w = height // self.patch_size, width // self.patch_size
        levels = []
        for project, resize, layer in zip(self.projects, self.resize_layers, self.layers):
            x = tokens[layer][:, frames, self.patch_start_index :]
            x = self.norm(x.reshape(-1, x.shape[-2], x.shape[-1]))  # [B*s, h*w, 2C]
            x = x.permute(0, 2, 1).reshape(x.shape[0], x.shape[-1], grid_h, grid_w)
            x = add_uv_embedding(project(x), height, width)
            levels.append(resize(x))
        return self.scratch(levels)


def decode_in_chunks(decode: Callable[[slice], torch.Tensor], batch: int, frames: int) -> torch.Tensor:
    """Run `decode(frame slice) -> [B*s, K, H, W]` over chunks of frames -> [B, S, K, H, W]."""
    chunks = []
    for start in range(0, frames, FRAMES_PER_CHUNK):
        chunk = slice(start, min(start + FRAMES_PER_CHUNK, frames))
        out = decode(chunk)
        chunks.append(out.reshape(batch, chunk.stop - chunk.start, *out.shape[1:]))
    return torch.cat(chunks, dim=1)


class DepthHead(DPTHead):
    """-> depth = exp(x) and confidence = 1 + exp(c), each [B, S, H, W]."""

    def __init__(self, architecture: Architecture):
        super().__init__(architecture)
        half = architecture.dpt_features // 2
        self.scratch.output_conv2 = nn.Sequential(
            nn.Conv2d(half, architecture.depth_head_hidden, kernel_size=3, padding=1),
            nn.ReLU(),
            nn.Conv2d(architecture.depth_head_hidden, 2, kernel_size=1),
        )

    def decode(self, tokens: dict[int, torch.Tensor], images: torch.Tensor, frames: slice) -> torch.Tensor:
        """-> raw [B*s, 2, H, W] (log depth, log(confidence - 1)) for the frames in `frames`."""
        height, width = images.shape[-2:]
        out = self.fused_features(tokens, frames, (height, width))
        grid_h, grid_w = height // self.patch_size, width // self.patch_size
        out = F.interpolate(out, size=(grid_h * self.patch_size, grid_w * self.patch_size), mode="bilinear", align_corners=True)
        return self.scratch.output_conv2(add_uv_embedding(out, height, width))

    def forward(self, tokens: dict[int, torch.Tensor], images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """-> depth [B, S, H, W] (> 0), confidence [B, S, H, W] (> 1)."""
        raw = decode_in_chunks(lambda frames: self.decode(tokens, images, frames), *images.shape[:2])
        depth = raw[:, :, 0].clamp(-MAX_LOG_VALUE, MAX_LOG_VALUE).exp()
        return depth, 1 + raw[:, :, 1].clamp(max=MAX_LOG_VALUE).exp()
