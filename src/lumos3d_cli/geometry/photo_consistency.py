"""Depth that the neighbouring photos agree on: a plane sweep scored by normalised cross-correlation.

The network's depth, aligned to the sparse points (`geometry.depth_alignment`, a smooth
correction on top), is right at the points and smooth between them; on fine structure (foliage,
a chart propped on a shrub) it is off by a few per cent, and each view's Gaussians then land
beside their neighbours' copies of the same surface: the fused scene blurs and ghosts. Multi-view
stereo fixes that where the photos have texture (as COLMAP's PatchMatch and MVSNet's cost volume
score depth hypotheses by photo-consistency; COLMAP's runs only on CUDA):

for every pixel of a view, depths d (1 + f) for `hypotheses` factors f evenly in [-span, span]
are each projected into the view's nearest fused neighbours, the neighbour's photo is sampled
there (a neighbour counts when it sees the view's scene, the point on its axis at its median
depth, at a triangulation angle within [`min_angle`, `max_angle`]: under a few degrees a depth
change hardly moves the window, so its best score is noise, and beyond about 15 degrees the
windows, taken square in each photo, no longer cover the same surface; a view with no such
neighbour keeps its depth, as multi-view stereo selects its source views by that angle), and
the hypothesis is scored by the NCC of a (2 radius + 1)² window around the pixel
(invariant to each photo's gain and offset, so over- and under-exposed photos compare alike).
Each hypothesis keeps the mean of its `best` neighbours' scores (a neighbour whose photo does
not hold the whole window drops out; an occluded one scores low and is not among the best). The best hypothesis, refined by a parabola
through its neighbours, replaces the depth where its score is at least `min_score`, at least `min_contrast`
above the lowest score of the swept depths (a score that hardly changes with depth comes from a
baseline too short for the depth, and its best is noise), where a neighbour sees the window at the
depth as it was, and inside the swept range. A new depth is then kept only where it lands within
`max_disagreement` (relative) of some neighbour's own swept depth, as multi-view stereo's fusion
checks geometric consistency: a repeated pattern or a single neighbour can make a wrong depth score
best in one view, but the neighbour that swept the same surface does not put it there. Elsewhere
(no texture, clipped or black photos, noise the neighbours do not share, views close together)
the depth stays as it was.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from lumos3d_cli.checks import require_finite
from lumos3d_cli.geometry.confirmed_depth import compare_with_neighbour
from lumos3d_cli.geometry.sweep_settings import DepthSweepSettings
from lumos3d_cli.geometry.vector_angles import angle_between
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.model.geometry import unproject_depth

# Variance floor of a window (grey levels in [0, 1], squared): a window flatter than a standard
# deviation of 0.005 (about 1.3 levels of 255) has no texture to match, and with both deviations
# clamped here its score stays near 0. It also keeps the float32 rounding of the running sums
# (up to about 1e-6 in a window's variance at these sizes) from scoring near-flat dark or clipped
# windows with faint noise as matches.
_VARIANCE_FLOOR = 0.005 ** 2


@dataclass
class DepthSweep:
    """depth [V, h, w] (the input's dtype); changed [V, h, w] bool: the pixels whose depth the
    sweep replaced; share: their fraction over the views that had neighbours; seconds;
    views_without_neighbours: the views that take part but kept their depth because no other
    camera triangulates them within the angles."""

    depth: torch.Tensor
    changed: torch.Tensor
    share: float
    seconds: float
    views_without_neighbours: int = 0

    def summary(self, settings: DepthSweepSettings) -> dict:
        return {"changed_pixels": round(self.share, 4), "seconds": round(self.seconds, 3),
                "neighbours": settings.neighbours, "span": settings.span, "hypotheses": settings.hypotheses,
                "window_px": 2 * settings.radius + 1, "min_score": settings.min_score,
                "min_contrast": settings.min_contrast, "angles_deg": [settings.min_angle, settings.max_angle],
                "max_disagreement": settings.max_disagreement,
                "views_without_neighbours": self.views_without_neighbours}


def box_mean(values: torch.Tensor, radius: int) -> torch.Tensor:
    """[..., h, w] -> the mean over each (2 radius + 1)² window, the border replicated: two
    running sums (one per axis), so the cost does not grow with the window."""
    size = 2 * radius + 1
    rows = F.pad(values, (radius + 1, radius, 0, 0), mode="replicate").cumsum(-1)
    values = rows[..., size:] - rows[..., :-size]
    columns = F.pad(values, (0, 0, radius + 1, radius), mode="replicate").cumsum(-2)
    return (columns[..., size:, :] - columns[..., :-size, :]) / (size * size)


def require_sweep_inputs(sweep: str, depth: torch.Tensor, cameras: Cameras, images: torch.Tensor) -> None:
    """ValueError unless depth [V, h, w] is positive, with V cameras and images [V, 3, H, W];
    NonFiniteError for NaN or Inf in the depth or the images. `sweep` names the caller."""
    views = depth.shape[0]
    if images.dim() != 4 or images.shape[:2] != (views, 3) or len(cameras) != views:
        raise ValueError(f"images {tuple(images.shape)} and {len(cameras)} cameras must match depth {tuple(depth.shape)}")
    require_finite("depth", depth)
    require_finite("images", images)
    if not bool((depth > 0).all()):
        raise ValueError(f"the {sweep} needs positive depth everywhere")


def grey_windows(images: torch.Tensor, height: int, width: int, radius: int) -> tuple[torch.Tensor, ...]:
    """images [V, 3, H, W] -> (grey [V, 1, height, width] area-resized and centred on 0, the mean
    and the standard deviation of each (2 radius + 1)² window [V, 1, height, width], the
    deviation floored at `_VARIANCE_FLOOR`): what `window_scores` compares, in float32."""
    grey = F.interpolate(images.float(), size=(height, width), mode="area").mean(1, keepdim=True)
    grey = grey - 0.5  # centred: the window sums lose less to float32 rounding
    mean = box_mean(grey, radius)
    deviation = (box_mean(grey * grey, radius) - mean.square()).clamp_min(_VARIANCE_FLOOR).sqrt()
    return grey, mean, deviation


def triangulation_angles(cameras: Cameras, depth: torch.Tensor) -> torch.Tensor:
    """[V, V] degrees: for each view v (row), the angle at the point on v's optical axis at v's
    median depth between the rays from v's centre and from each other camera's centre to it (the
    angle the two photos triangulate v's scene at; 0 on the diagonal). depth [V, h, w] in the
    cameras' units. In float64: the angles do not depend on the scene's scale."""
    rotation = cameras.extrinsics[:, :, :3].double()
    centres = cameras.centers().double()
    axes = rotation[:, 2, :]  # each camera's +z (viewing direction) in world coordinates
    seen = centres + depth.double().flatten(1).median(dim=1).values[:, None] * axes  # [V, 3]
    # [V (point), 1, 3] against [V (point), V (camera), 3]
    return angle_between((seen - centres)[:, None, :], seen[:, None, :] - centres[None, :, :])


def _neighbours(cameras: Cameras, depth: torch.Tensor, settings: DepthSweepSettings,
                allowed: torch.Tensor) -> list[list[int]]:
    """For each view, up to `settings.neighbours` nearest other cameras (by centre) among the
    `allowed` ones whose triangulation angle at the view's median depth lies within
    [`settings.min_angle`, `settings.max_angle`] degrees."""
    centres = cameras.centers().double()
    distances = torch.cdist(centres, centres)
    angles = triangulation_angles(cameras, depth)
    usable = allowed.to(angles.device)[None, :] & (angles >= settings.min_angle) & (angles <= settings.max_angle)
    distances[~usable] = float("inf")
    distances.fill_diagonal_(float("inf"))
    order = distances.argsort(dim=1)
    return [[int(o) for o in order[view] if torch.isfinite(distances[view, o])][:settings.neighbours]
            for view in range(len(cameras))]


def depth_agreement(depth: torch.Tensor, changed: torch.Tensor, cameras: Cameras, neighbours: list[list[int]],
                    tolerance: float) -> torch.Tensor:
    """[V, h, w] bool: the changed pixels ([V, h, w] bool) whose new depth (depth [V, h, w], after
    the sweep) lands in at least one of the view's `neighbours` within `tolerance` (relative) of
    that neighbour's own depth there (its nearest pixel: no blend across a depth edge; fusion's
    check, `geometry.confirmed_depth`, confirms a pixel the same way). cameras [V] in the
    depth's dtype, intrinsics in pixels of the depth maps."""
    world = unproject_depth(depth, cameras.extrinsics, cameras.intrinsics)  # [V, h, w, 3]
    agreed = torch.zeros_like(changed)
    for view, others in enumerate(neighbours):
        if not bool(changed[view].any()):
            continue
        for other in others:
            agreed[view] |= compare_with_neighbour(world[view], depth, cameras, other, tolerance)[0]
    return agreed & changed


def window_scores(grey: torch.Tensor, mean: torch.Tensor, deviation: torch.Tensor, cameras: Cameras, view: int,
                  others: list[int], points: torch.Tensor, factors: torch.Tensor, radius: int) -> torch.Tensor:
    """[N, J, h, w] NCC of `view`'s windows with each neighbour's photo sampled at the J depth
    hypotheses; -inf where a hypothesis takes part of the window out of a neighbour's photo or
    behind it. points [h, w, 3]: the view's pixels in its camera frame at the current depth (a
    hypothesis scales them)."""
    height, width = grey.shape[-2:]
    rotation, translation = cameras.extrinsics[view, :, :3], cameras.extrinsics[view, :, 3]
    scores = []
    for other in others:
        other_rotation, other_translation = cameras.extrinsics[other, :, :3], cameras.extrinsics[other, :, 3]
        relative = other_rotation @ rotation.T  # view's camera frame -> other's
        offset = other_translation - relative @ translation
        # a depth factor scales the point in the view's frame, so it scales its rotated copy too
        rotated = (points @ relative.T).unbind(-1)  # 3 x [h, w]
        scale = (1 + factors)[:, None, None]
        x, y, z = (scale * rotated[axis] + offset[axis] for axis in range(3))  # [J, h, w] each
        intrinsics = cameras.intrinsics[other]
        safe = z.clamp_min(1e-12)
        gx = (intrinsics[0, 0] * x / safe + intrinsics[0, 2]) * (2 / width) - 1
        gy = (intrinsics[1, 1] * y / safe + intrinsics[1, 2]) * (2 / height) - 1
        visible = (z > 0) & (gx.abs() < 1) & (gy.abs() < 1)
        sampled = F.grid_sample(grey[other][None].expand(len(factors), -1, -1, -1), torch.stack([gx, gy], dim=-1),
                                mode="bilinear", align_corners=False, padding_mode="border")  # [J, 1, h, w]
        moments = box_mean(torch.cat([sampled, sampled * sampled, sampled * grey[view][None],
                                      visible[:, None].to(sampled.dtype)], dim=1), radius)
        sampled_mean = moments[:, 0]
        sampled_deviation = (moments[:, 1] - sampled_mean.square()).clamp_min(_VARIANCE_FLOOR).sqrt()
        ncc = (moments[:, 2] - sampled_mean * mean[view]) / (sampled_deviation * deviation[view])
        # the whole window must land inside the neighbour's photo: a window that runs off its edge
        # compares the clamped border, and a wrong depth that keeps it inside would win there
        whole = moments[:, 3] > 1 - 1e-3
        scores.append(torch.where(whole, ncc, torch.full_like(ncc, -torch.inf)))
    return torch.stack(scores)


def mean_of_best(scores: torch.Tensor, count: int) -> tuple[torch.Tensor, torch.Tensor]:
    """scores [N, J, h, w] (-inf: not seen) -> (the mean of the `count` highest seen scores per
    hypothesis [J, h, w], -1 where none is seen; [J, h, w] whether any neighbour sees the
    hypothesis). The highest taken one at a time: for the few neighbours here, faster than a
    top-k across the first dimension."""
    remaining = scores.clone()
    total = torch.zeros(scores.shape[1:], dtype=scores.dtype, device=scores.device)
    seen = torch.zeros(scores.shape[1:], dtype=scores.dtype, device=scores.device)
    for _ in range(count):
        highest, which = remaining.max(0)
        finite = torch.isfinite(highest)
        total += torch.where(finite, highest, torch.zeros_like(highest))
        seen += finite
        remaining.scatter_(0, which[None], -torch.inf)
    mean = torch.where(seen > 0, total / seen.clamp_min(1), torch.full_like(total, -1.0))
    return mean, seen > 0


def sweep_depth(
    depth: torch.Tensor, cameras: Cameras, images: torch.Tensor, settings: DepthSweepSettings | None = None,
    neighbour_views: Sequence[bool] | None = None,
) -> DepthSweep:
    """depth [V, h, w] (positive, one frame), cameras [V] with intrinsics in pixels of the depth
    maps, images [V, 3, H, W] in [0, 1] (any size: area-resized to the depth maps) -> DepthSweep
    (module docstring). neighbour_views [V] bool: the views that take part (None: all):
    evaluation's held-out views are neither compared with nor swept (their Gaussians are not
    fused). A view with no neighbour that takes part keeps its depth.
    Runs in float32 on the depth's device."""
    settings = settings or DepthSweepSettings()
    started = time.perf_counter()
    views, height, width = depth.shape
    require_sweep_inputs("depth sweep", depth, cameras, images)
    device = depth.device
    allowed = (torch.ones(views, dtype=torch.bool) if neighbour_views is None
               else torch.tensor([bool(v) for v in neighbour_views], dtype=torch.bool))
    cameras = cameras.to(device=device, dtype=torch.float32)
    working = depth.float()
    grey, mean, deviation = grey_windows(images.to(device), height, width, settings.radius)
    factors = torch.linspace(-settings.span, settings.span, settings.hypotheses, device=device)
    step = float(factors[1] - factors[0])
    middle = settings.hypotheses // 2
    # each view's pixels in its own camera frame at the current depth (identity extrinsics)
    identity = torch.eye(3, 4, device=device).expand(views, 3, 4)
    points = unproject_depth(working, identity, cameras.intrinsics)  # [V, h, w, 3]
    refined = depth.clone()
    changed = torch.zeros(depth.shape, dtype=torch.bool, device=device)
    neighbours = _neighbours(cameras, working, settings, allowed)
    for view, others in enumerate(neighbours):
        if not others or not bool(allowed[view]):  # a held-out view's Gaussians are not fused
            continue
        scores = window_scores(grey[:, 0], mean[:, 0], deviation[:, 0], cameras, view, others, points[view], factors,
                               settings.radius)
        # the mean of the best neighbours that see the window: a neighbour that does not is left
        # out, not scored -1 (else a wrong depth that brings a second neighbour in would win)
        score, seen = mean_of_best(scores, min(settings.best, len(others)))  # [J, h, w] each
        best_score, best = score.max(0)
        inner = best.clamp(1, settings.hypotheses - 2)
        below, at, above = (score.gather(0, (inner + shift)[None])[0] for shift in (-1, 0, 1))
        curvature = below - 2 * at + above
        # the parabola's vertex, within half a step of the best hypothesis
        vertex = torch.where(curvature < -1e-6, 0.5 * (below - above) / curvature.clamp_max(-1e-6),
                             torch.zeros_like(curvature)).clamp(-0.5, 0.5)
        factor = factors[best] + vertex * step
        # only where a neighbour sees the window at the current depth: at the edge of the overlap
        # a depth that moves the window into a neighbour's photo has nothing to be compared with
        # the contrast over the swept depths that some neighbour sees
        lowest = torch.where(seen, score, torch.full_like(score, torch.inf)).amin(0)
        accept = ((best_score >= settings.min_score) & (best_score >= lowest + settings.min_contrast) & seen[middle]
                  & (best > 0) & (best < settings.hypotheses - 1))
        refined[view] = torch.where(accept, depth[view] * (1 + factor.to(depth.dtype)), depth[view])
        changed[view] = accept
    if settings.max_disagreement > 0:
        # a wrong depth that one neighbour's photo happens to match (a repeated pattern, few
        # views) lands where no neighbour's own sweep put the surface; a right one agrees with
        # the neighbour that swept the same surface
        changed = depth_agreement(refined.float(), changed, cameras, neighbours, settings.max_disagreement)
        refined = torch.where(changed, refined, depth)
    compared = [view for view, others in enumerate(neighbours) if others and bool(allowed[view])]
    share = float(changed[compared].float().mean()) if compared else 0.0
    return DepthSweep(refined, changed, share, time.perf_counter() - started, int(allowed.sum()) - len(compared))
