"""Fields of view no lens has: the camera head's fallback for a view it cannot read.

The camera head predicts each view's field of view through a ReLU, and on some photos (a single
night photo: no parallax, few cues) it predicts 0, which decodes to a focal length of 10^5
pixels or more. Geometry built on it is degenerate: the pixel Gaussians, sized for a normal lens,
each cover the whole image. Such a view gets a typical phone or kit lens instead; a view with
a plausible field of view keeps the network's.
"""

from __future__ import annotations

import math

import torch

# Fields of view of the longer image side outside this range (degrees) are taken as a failed
# prediction: a 600 mm telephoto sees about 4 degrees on a 35 mm frame, so 3 leaves room for
# real long lenses; fisheyes beyond 150 degrees are not pinhole cameras at all.
PLAUSIBLE_FOV_DEGREES = (3.0, 150.0)
# The fallback: about a 30 mm lens on a 35 mm frame, a phone's main camera.
FALLBACK_FOV_DEGREES = 60.0
# Pixels no camera has: focal lengths across and down further apart than this ratio.
MAX_PIXEL_ASPECT = 2.0


def longer_side_fov(intrinsics: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """intrinsics [V, 3, 3] of images of size (width, height) -> [V] field of view of the
    longer side, in degrees."""
    width, height = size
    side, focal = (width, intrinsics[:, 0, 0]) if width >= height else (height, intrinsics[:, 1, 1])
    return torch.rad2deg(2 * torch.atan(side / 2 / focal.clamp_min(1e-12)))


# Fields of view that cameras from structure-from-motion or a camera file may have: down to a
# 2000 mm lens on a 35 mm frame (an 800 mm super-telephoto sees 2.6 degrees, under the network's
# fallback bound). SfM on few features has settled on 0.25 degrees for a phone photo.
MEASURED_FOV_DEGREES = (1.0, PLAUSIBLE_FOV_DEGREES[1])


def implausible_views(intrinsics: torch.Tensor, sizes: list[tuple[int, int]]) -> dict[int, float]:
    """intrinsics [V, 3, 3] of images of `sizes` (width, height, one per view) -> {view: field of
    view in degrees, across or down, whichever is outside MEASURED_FOV_DEGREES (or not finite)}:
    cameras that structure-from-motion or a camera file gave, which no lens has (a focal length
    of 1e30 px down alone rendered black frames)."""
    low, high = MEASURED_FOV_DEGREES
    found = {}
    for view, (width, height) in enumerate(sizes):
        focal = intrinsics[view].double()
        for side, length in ((width, focal[0, 0]), (height, focal[1, 1])):
            degrees = float(torch.rad2deg(2 * torch.atan(side / 2 / length.clamp_min(1e-12))))
            if not (math.isfinite(degrees) and low <= degrees <= high):
                found[view] = degrees
                break
    return found


def plausible_intrinsics(intrinsics: torch.Tensor, size: tuple[int, int],
                         stretch: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """intrinsics [V, 3, 3] of images of size (width, height) -> (intrinsics [V, 3, 3], replaced
    [V] bool), judging each view as its photo: views whose field of view of the photo's longer side
    is outside PLAUSIBLE_FOV_DEGREES (or not finite) get square pixels and FALLBACK_FOV_DEGREES
    there; views whose pixels are further from square than MAX_PIXEL_ASPECT (the head's field of
    view for the shorter side alone failed: a focal length of 134,000 pixels down against 817
    across) get square pixels at the longer side's focal length. `stretch` [V]: each photo's own
    width over `size`'s width, divided by its own height over `size`'s height (a photo of another
    aspect ratio stretched to `size`: its pixels are square at its own size, not here, and its
    longer side may be the other one); None: 1. A field of view across or down is the same at any
    scale, so it is judged here. The principal point is kept."""
    width, height = size
    own = torch.ones(len(intrinsics), dtype=torch.float64) if stretch is None else stretch.double().cpu()
    fx, fy = intrinsics[:, 0, 0].double().cpu(), intrinsics[:, 1, 1].double().cpu()
    across = (width / height) * own >= 1  # the photo's own longer side
    fov = torch.rad2deg(2 * torch.atan(torch.where(across, width / 2 / fx, height / 2 / fy)))
    low, high = PLAUSIBLE_FOV_DEGREES
    plausible = torch.isfinite(fov) & (fov >= low) & (fov <= high)
    aspect = fx / fy * own  # fx / fy at the photo's own size
    square = torch.isfinite(aspect) & (aspect >= 1 / MAX_PIXEL_ASPECT) & (aspect <= MAX_PIXEL_ASPECT)
    replaced = ~(plausible & square)
    if not bool(replaced.any()):
        return intrinsics, replaced.to(intrinsics.device)
    tangent = math.tan(math.radians(FALLBACK_FOV_DEGREES) / 2)
    longer_focal = torch.where(across, torch.where(plausible, fx, width / 2 / tangent),
                               torch.where(plausible, fy, height / 2 / tangent))
    # square at the photo's own size, where fx / fy is the ratio here times the stretch
    new_fx = torch.where(across, longer_focal, longer_focal / own)
    new_fy = torch.where(across, longer_focal * own, longer_focal)
    fixed = intrinsics.clone()
    rows = replaced.to(intrinsics.device)
    fixed[rows, 0, 0] = new_fx.to(fixed)[rows]
    fixed[rows, 1, 1] = new_fy.to(fixed)[rows]
    return fixed, rows


# Structure-from-motion's focal lengths and the network's further apart than this (median ratio)
# mean one of them settled on a wrong one: four of buu's photos at 250 px gave SfM 843 px, the
# network 265, the reference 368 (all eight: SfM 365).
FOCAL_DISAGREEMENT = 2.0


def focal_ratio(measured: torch.Tensor, predicted: torch.Tensor) -> float:
    """intrinsics [V, 3, 3] of the same views at the same image size, measured (structure-from-
    motion) and predicted (the network) -> the median of their focal lengths' ratio (fx and fy)."""
    ratios = torch.cat([measured[:, 0, 0] / predicted[:, 0, 0], measured[:, 1, 1] / predicted[:, 1, 1]])
    return float(ratios.double().median())
