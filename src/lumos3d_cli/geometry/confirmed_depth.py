"""Which pixels' depth the neighbouring views confirm: the geometric consistency check of
multi-view stereo fusion (as in COLMAP's and MVSNet's depth fusion), used to keep a view's
Gaussians out of the scene where its depth contradicts what its neighbours see.

A pixel of view v, unprojected with its depth and projected into a neighbour n, is
- confirmed when its depth there agrees with n's depth within `tolerance` (relative);
- contradicted when it lies clearly in front of n's surface (depth below (1 - tolerance) of it):
  n sees through that point, so it is not there (a floater that would be pasted over n's view);
- unknown when it falls outside n's image or behind n's surface (occluded from n).
A pixel is kept unless a neighbour contradicts it and none confirms it, and then only dropped where
the neighbours' kept pixels, projected into its view, cover its place: at the border of a view that
its neighbours barely overlap, a dropped pixel would leave a hole that shows the background (a
black wedge at the edge of a `make demo` view), which is worse than a possibly misplaced surface.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from lumos3d_cli.geometry.reprojection import inside_view, land_in_view, sample_map
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.model.geometry import unproject_depth

DEFAULT_TOLERANCE = 0.05
DEFAULT_NEIGHBOURS = 4


def neighbours_by_distance(cameras: Cameras, count: int) -> torch.Tensor:
    """[V, min(count, V-1)] int64: each camera's nearest other cameras by centre distance (of equally
    near ones the lower index first)."""
    centres = cameras.centers().double()
    distances = torch.cdist(centres, centres)
    distances.fill_diagonal_(float("inf"))
    return distances.argsort(dim=1, stable=True)[:, : min(count, len(cameras) - 1)]


def compare_with_neighbour(world: torch.Tensor, depth: torch.Tensor, cameras: Cameras, other: int, tolerance: float):
    """(confirmed [h, w], contradicted [h, w]) of one view's pixels, unprojected to world [h, w, 3],
    against `other`'s depth."""
    u, v, z = land_in_view(world.reshape(-1, 3), cameras, other)
    inside = inside_view(u, v, z, depth.shape[-2:])
    seen = sample_map(depth[other], u, v, mode="nearest")
    confirmed = inside & ((z - seen).abs() <= tolerance * seen)
    contradicted = inside & (z < (1 - tolerance) * seen)
    return confirmed.reshape(world.shape[:2]), contradicted.reshape(world.shape[:2])


def confirmed_pixels(
    depth: torch.Tensor, cameras: Cameras, tolerance: float = DEFAULT_TOLERANCE, neighbours: int = DEFAULT_NEIGHBOURS,
) -> torch.Tensor:
    """depth [V, h, w] (positive, one frame) and cameras with intrinsics in pixels of the depth
    maps -> keep [V, h, w] bool (see the module's rule). With one view everything is kept."""
    views = depth.shape[0]
    keep = torch.ones(depth.shape, dtype=torch.bool)
    if views < 2:
        return keep
    nearest = neighbours_by_distance(cameras, neighbours)
    # float32 is ample for a 5 % test and halves the work of these [V, h, w] passes
    depth = depth.float()
    world = unproject_depth(depth, cameras.extrinsics.float(), cameras.intrinsics.float())  # [V, h, w, 3]
    for view in range(views):
        confirmed = torch.zeros(depth.shape[1:], dtype=torch.bool)
        contradicted = torch.zeros(depth.shape[1:], dtype=torch.bool)
        for other in nearest[view].tolist():
            yes, no = compare_with_neighbour(world[view], depth, cameras, other, tolerance)
            confirmed |= yes
            contradicted |= no
        keep[view] = confirmed | ~contradicted
    # Cover is measured with the first pass's kept pixels, so no view's result depends on the
    # order the views are visited in.
    first_pass = keep.clone()
    for view in range(views):
        dropped = ~first_pass[view]
        if bool(dropped.any()):
            covered = torch.zeros(depth.shape[1:], dtype=torch.bool)
            for other in nearest[view].tolist():
                covered |= projected_cover(world[other][first_pass[other]], cameras, view, depth.shape[1:])
            keep[view] |= dropped & ~covered
    return keep


def projected_cover(world: torch.Tensor, cameras: Cameras, view: int, size: tuple[int, int]) -> torch.Tensor:
    """[h, w] bool: the pixels of `view` (intrinsics in pixels of an h x w frame) that points
    world [N, 3] in front of it land on, grown by one pixel on every side: another view's pixel
    grid seldom lands on every one of this view's pixels, and a gap of one pixel is not a hole
    that a neighbour's Gaussians (about a pixel wide) leave open."""
    height, width = size
    pixels, z = cameras[[view]].to(world.dtype).project(world)
    u, v, z = pixels[0, :, 0].floor(), pixels[0, :, 1].floor(), z[0]
    # tested in floating point: a point just in front of the camera projects to +-inf (or NaN)
    inside = (z > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    hits = torch.zeros(height * width, dtype=torch.float32)
    hits[v[inside].long() * width + u[inside].long()] = 1.0
    return F.max_pool2d(hits.reshape(1, 1, height, width), 3, stride=1, padding=1)[0, 0] > 0
