"""How much of the world one pixel covers at each point, and voxel sizes that follow it.

A pixel of a view at camera depth z spans z / f world units (f the focal length in pixels). A
pixel Gaussian's footprint is that span in the finest view that holds it: a function of the
position, not of the view that made the Gaussian, so the Gaussians several views place on the same
surface get the same voxel size and can fuse. It is measured at the network's image (the grid of
pixel Gaussians), not at the photos: one Gaussian per network pixel is all the detail the scene
holds (its colour too is the photo averaged over that pixel, `model.appearance.footprint`), so a
voxel finer than a network pixel only keeps duplicates apart.

Voxel sizes are powers of two times the scene scale, the largest not above a multiple of the
footprint: a handful of nested grids whose cells grow with depth (one global size either merges
distinct near pixels or none of the far duplicates). With the multiple 1 a voxel is never wider
than a pixel of any view that holds it, so it merges the Gaussians several views place on one
spot and seldom two neighbouring pixels of one view (they lie at least a footprint apart): the
scene keeps the network's resolution. Larger multiples trade that resolution for fewer Gaussians.
"""

from __future__ import annotations

import torch

# Voxel sizes stay within 2^+-40 scene scales, so round(x / size) fits int64 for any point
# within 2^20 scene scales of the origin even where a footprint is 0 or huge.
MAX_LEVEL = 40
# The multiple of the footprint for `lumos3d restore` (times the preset's voxel_scale): chosen on
# normal-light scenes with benchmarks/gaussian_budget.py.
DEFAULT_FOOTPRINT_SCALE = 1.0
_CHUNK = 131_072  # points per step: bounds the [V, chunk, 3] camera-space buffer


def pixel_footprint(
    points: torch.Tensor, extrinsics: torch.Tensor, intrinsics: torch.Tensor, size: tuple[int, int]
) -> torch.Tensor:
    """points [N, 3], extrinsics [V, 3, 4] world->camera, intrinsics [V, 3, 3] of images of
    size (width, height) -> [N] the smallest z / sqrt(fx fy) over the views whose image holds
    the point in front of the camera (inf where none does)."""
    rotations = extrinsics[:, :, :3].to(points)
    translations = extrinsics[:, :, 3].to(points)
    intrinsics = intrinsics.to(points)
    focal = (intrinsics[:, 0, 0] * intrinsics[:, 1, 1]).sqrt()[:, None]
    width, height = size
    footprints = []
    for start in range(0, points.shape[0], _CHUNK):
        local = torch.einsum("vij,nj->vni", rotations, points[start:start + _CHUNK]) + translations[:, None]
        depth = local[..., 2]
        safe = torch.where(depth > 0, depth, torch.ones_like(depth))
        u = intrinsics[:, 0, 0, None] * local[..., 0] / safe + intrinsics[:, 0, 2, None]
        v = intrinsics[:, 1, 1, None] * local[..., 1] / safe + intrinsics[:, 1, 2, None]
        inside = (depth > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
        footprint = torch.where(inside, depth / focal, torch.full_like(depth, float("inf")))
        footprints.append(footprint.amin(dim=0))
    return torch.cat(footprints) if footprints else points.new_zeros(0)


def footprint_voxel_sizes(footprint: torch.Tensor, multiple: float, unit: torch.Tensor | float) -> torch.Tensor:
    """footprint [...] world units, multiple > 0, unit (the scene scale) -> [...] voxel sizes
    relative to the unit: 2^floor(log2(multiple * footprint / unit)), between half the multiple
    of the footprint and the multiple, levels clamped to +-MAX_LEVEL. A point no view holds
    (infinite footprint) gets the smallest size: it fuses with nothing rather than with every
    other such point."""
    if not multiple > 0:
        raise ValueError(f"footprint multiple {multiple} must be positive")
    relative = torch.where(torch.isfinite(footprint), multiple * footprint / unit, torch.zeros_like(footprint))
    level = torch.log2(relative.clamp(min=2.0**-MAX_LEVEL, max=2.0**MAX_LEVEL)).floor()
    return torch.exp2(level)
