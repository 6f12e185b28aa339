"""Geometric augmentation of a multi-view sample, keeping the cameras consistent: one random
crop for all views, resized to the network size, and an optional mirror of the whole scene."""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

# Mirroring image x is a reflection; applying it to the camera frame (F) and to the world (M)
# keeps every rotation proper: R' = F R M, t' = F t, X' = M X.
_MIRROR = torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64))


def crop_box(width: int, height: int, out_width: int, out_height: int, scale: float, rng: np.random.Generator) -> tuple[int, int, int, int]:
    """(x0, y0, crop_width, crop_height): the output's aspect ratio, covering `scale` of the
    largest such box that fits, at a random position."""
    aspect = out_width / out_height
    full_width = min(width, height * aspect)
    crop_width = max(1, int(round(full_width * math.sqrt(scale))))
    crop_height = max(1, min(height, int(round(crop_width / aspect))))
    x0 = int(rng.integers(0, width - crop_width + 1))
    y0 = int(rng.integers(0, height - crop_height + 1))
    return x0, y0, crop_width, crop_height


def centred_box(width: int, height: int, out_width: int, out_height: int) -> tuple[int, int, int, int]:
    """(x0, y0, crop_width, crop_height): the largest box of the output's aspect ratio, centred."""
    aspect = out_width / out_height
    crop_width = max(1, min(width, int(round(height * aspect))))
    crop_height = max(1, min(height, int(round(crop_width / aspect))))
    return (width - crop_width) // 2, (height - crop_height) // 2, crop_width, crop_height


def crop_and_resize(
    images: torch.Tensor, intrinsics: torch.Tensor | None, box: tuple[int, int, int, int], out_width: int, out_height: int
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """images [V,3,H,W] -> [V,3,out_height,out_width]; intrinsics [V,3,3] follow the crop."""
    x0, y0, crop_width, crop_height = box
    cropped = images[..., y0 : y0 + crop_height, x0 : x0 + crop_width]
    resized = F.interpolate(cropped, size=(out_height, out_width), mode="bilinear", align_corners=False, antialias=True)
    if intrinsics is None:
        return resized.clamp(0, 1), None
    scaled = intrinsics.clone()
    sx, sy = out_width / crop_width, out_height / crop_height
    scaled[:, 0, 0] *= sx
    scaled[:, 0, 2] = (scaled[:, 0, 2] - x0) * sx
    scaled[:, 1, 1] *= sy
    scaled[:, 1, 2] = (scaled[:, 1, 2] - y0) * sy
    return resized.clamp(0, 1), scaled


def mirror(
    images: torch.Tensor, intrinsics: torch.Tensor | None, extrinsics: torch.Tensor | None, points: np.ndarray | None
) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None, np.ndarray | None]:
    """Mirror every view left-right and the scene with it (cameras and points stay consistent):
    images [V, 3, H, W], intrinsics [V, 3, 3] and extrinsics [V, 3, 4] (world->camera) when
    given, points [P, 3] when given -> the same, mirrored."""
    images = images.flip(-1)
    if intrinsics is not None:
        intrinsics = intrinsics.clone()
        intrinsics[:, 0, 2] = images.shape[-1] - intrinsics[:, 0, 2]
    if extrinsics is not None:
        mirror_matrix = _MIRROR.to(extrinsics)
        rotation = mirror_matrix @ extrinsics[:, :, :3] @ mirror_matrix
        translation = mirror_matrix @ extrinsics[:, :, 3:]
        extrinsics = torch.cat([rotation, translation], dim=2)
    if points is not None:
        points = points * np.array([-1.0, 1.0, 1.0])
    return images, intrinsics, extrinsics, points
