"""Sine-cosine embedding of normalised image coordinates, added to DPT feature maps (VGGT)."""

from __future__ import annotations

import torch

# The embedding is added with this weight (VGGT's DPT uses 0.1).
EMBEDDING_WEIGHT = 0.1


def uv_grid(grid_height: int, grid_width: int, aspect_ratio: float, dtype, device) -> torch.Tensor:
    """[h, w, 2] (u, v) cell centres of an h x w grid over an image of the given width/height
    ratio, scaled so that the image diagonal has length 2 (corners at +-(ar, 1)/sqrt(ar^2 + 1))."""
    diagonal = (aspect_ratio**2 + 1.0) ** 0.5
    span_x, span_y = aspect_ratio / diagonal, 1.0 / diagonal
    xs = torch.linspace(-span_x * (grid_width - 1) / grid_width, span_x * (grid_width - 1) / grid_width, grid_width, dtype=dtype, device=device)
    ys = torch.linspace(-span_y * (grid_height - 1) / grid_height, span_y * (grid_height - 1) / grid_height, grid_height, dtype=dtype, device=device)
    return torch.stack(torch.meshgrid(xs, ys, indexing="xy"), dim=-1)


def _sincos(values: torch.Tensor, channels: int, omega_0: float = 100.0) -> torch.Tensor:
    """[M] -> [M, channels]: sin then cos of values times channels/2 geometric frequencies
    1 / omega_0^(j / (channels/2)), computed in float64."""
    omega = torch.arange(channels // 2, dtype=torch.float64, device=values.device) / (channels / 2.0)
    omega = 1.0 / omega_0**omega
    angles = values.reshape(-1).double()[:, None] * omega[None, :]
    return torch.cat((angles.sin(), angles.cos()), dim=1).float()


def uv_embedding(grid_height: int, grid_width: int, channels: int, aspect_ratio: float, dtype, device) -> torch.Tensor:
    """[channels, h, w]: the first half embeds u (x), the second half v (y)."""
    grid = uv_grid(grid_height, grid_width, aspect_ratio, dtype, device).reshape(-1, 2)
    embedding = torch.cat((_sincos(grid[:, 0], channels // 2), _sincos(grid[:, 1], channels // 2)), dim=-1)
    return embedding.reshape(grid_height, grid_width, channels).permute(2, 0, 1)


def add_uv_embedding(features: torch.Tensor, image_height: int, image_width: int) -> torch.Tensor:
    """features [N, C, h, w] + 0.1 * embedding of an h x w grid over the image's aspect ratio."""
    embedding = uv_embedding(
        features.shape[-2], features.shape[-1], features.shape[1], image_width / image_height, features.dtype, features.device
    )
    return features + EMBEDDING_WEIGHT * embedding
