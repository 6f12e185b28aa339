"""The scale of the network's depth in the frame of given cameras where no sparse points fix it:
one global scale swept over a log grid, scored by normalised cross-correlation with the
neighbouring photos.

With `--poses` and no structure-from-motion points (`--geometry network`, or structure-from-motion
failing on the photos) the network's depth is known in the given cameras' frame up to scale (the
network predicts every view's depth in one frame, nearly: on Strecha's wide-baseline Herz-Jesus the
views' own best scales spread over 10.8-15.3, on LOM buu within one step). The similarity between the network's
cameras and the given ones has that scale, but the bundled models' cameras nearly collapse onto
one pose (on LOM buu their mean distance apart is 0.006 of the given frame's 3.6 once scaled), so
its scale put the scene about ten times too far and every restored view was a ghosted jumble. The
given cameras are exact, and the photos they see agree only at the right depth: every view's
depth, scaled by each candidate, is projected into its nearest cameras' photos and scored by
window NCC as the per-pixel depth sweep scores its hypotheses (`geometry.photo_consistency`); the
scale the photos agree on best wins, where it stands out from the rest of the sweep. Each view
then takes its own best within an octave of it, where its own photos single one out (one scale
for all left Herz-Jesus's portal doubled, 23 % too far from the cameras).

The candidates are spaced by the ratio of the scene's median depth to the median distance from
each camera to its nearest other camera: from `MIN_DEPTH_RATIO` (the scene a quarter of a camera
spacing away) to `MAX_DEPTH_RATIO` (1,024 spacings: under 0.06 degrees of parallax between
neighbours, beyond which scales no longer differ in what the photos see).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from lumos3d_cli.geometry.photo_consistency import grey_windows, mean_of_best, require_sweep_inputs, window_scores
from lumos3d_cli.geometry.similarity import moved_to_origin
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.model.geometry import unproject_depth

MIN_DEPTH_RATIO = 0.25
MAX_DEPTH_RATIO = 1024.0
STEPS_PER_OCTAVE = 4
NEIGHBOURS = 4  # the nearest cameras by centre (no angle test: the angles depend on the scale swept)
BEST = 2  # the neighbours' scores averaged per candidate, as the depth sweep's `best`
RADIUS = 3  # the NCC window's half size in depth-map pixels, as the depth sweep's
# How far the best candidate's score must stand above the sweep's median: on LOM's low-light
# photos with their reference poses the right scale scores 0.29-0.45 above it (buu's 25 and 8
# photos, shrub's 35: the scene within 2 % of where structure-from-motion's points put it); black,
# clipped or textureless photos, noise the views do not share (0.006), smooth blobs (0.03) and one
# photo repeated in every view (0.06) say nothing about the scale.
MIN_CONTRAST = 0.15
# The depth-map pixels a view is swept at (the network's 224x168 is averaged to 112x84)
MAX_PIXELS = 12_000


@dataclass(frozen=True)
class ScaleSweep:
    """scale: the scene's factor for the depth (None: no candidate stands out, `contrast` below
    MIN_CONTRAST, or no view has another to be compared with); view_scales [V]: each view's own
    (module docstring; the scene's where the view's photos do not single one out); score: the
    scene's best candidate's mean agreement (the share-weighted NCC in [0, 1]); contrast: how far
    it stands above the sweep's median; candidates: how many scales were tried."""

    scale: float | None
    score: float
    contrast: float
    candidates: int
    view_scales: torch.Tensor | None = None

    def summary(self) -> dict:
        own = None if self.view_scales is None or self.scale is None else self.view_scales != self.scale
        return {"form": "photo-consistency scale", "scale": self.scale, "score": round(self.score, 4),
                "contrast": round(self.contrast, 4), "candidates": self.candidates,
                "views_with_their_own_scale": None if own is None else int(own.sum()),
                "view_scale_range": None if self.view_scales is None else
                [round(float(self.view_scales.min()), 6), round(float(self.view_scales.max()), 6)]}


def sweep_depth_scale(depth: torch.Tensor, cameras: Cameras, images: torch.Tensor,
                      views: Sequence[bool] | None = None) -> ScaleSweep:
    """depth [V, h, w] (positive, one frame up to scale), cameras [V] (the given ones, intrinsics
    in pixels of the depth maps), images [V, 3, H, W] in [0, 1] -> the ScaleSweep (module
    docstring). views [V] bool: the views that take part, compared and compared with (None: all;
    evaluation's held-out views take no part). Depth maps of more than MAX_PIXELS are
    area-averaged to fewer first (a scale is one number per view: a quarter of the pixels find it
    as well, in a quarter of the time). Runs in float32 on the depth's device, the cameras recentred
    in float64 first (poses in a geodetic frame, a million units from the origin, lose the
    spacing between cameras to float32 rounding)."""
    count = depth.shape[0]
    require_sweep_inputs("scale sweep", depth, cameras, images)
    taking_part = [v for v in range(count) if views is None or bool(views[v])]
    distances = _distinct_distances(cameras)
    candidates = _candidates(depth, distances, taking_part)
    if candidates is None:
        return ScaleSweep(None, 0.0, 0.0, 0)
    device = depth.device
    depth, cameras = _within_budget(depth, moved_to_origin(cameras, cameras.centers().double()[taking_part].mean(0)))
    height, width = depth.shape[-2:]
    cameras = cameras.to(device=device, dtype=torch.float32)
    grey, mean, deviation = grey_windows(images.to(device), height, width, RADIUS)
    identity = torch.eye(3, 4, device=device).expand(count, 3, 4)
    points = unproject_depth(depth.float(), identity, cameras.intrinsics)  # [V, h, w, 3] in each camera's frame
    factors = (candidates - 1).to(device=device, dtype=torch.float32)  # window_scores scales the points by 1 + factor
    per_view = torch.zeros(count, len(candidates), dtype=torch.float64)
    compared = []
    for view in taking_part:
        # a camera at the same centre (an exposure bracket's twin) sees the same at every scale
        others = sorted((o for o in taking_part if o != view and math.isfinite(float(distances[view, o]))),
                        key=lambda o: float(distances[view, o]))
        if not others:
            continue
        scores = window_scores(grey[:, 0], mean[:, 0], deviation[:, 0], cameras, view, others[:NEIGHBOURS],
                               points[view], factors, RADIUS)
        agreement, _ = mean_of_best(scores, min(BEST, len(scores)))  # [J, h, w]; -1 where no neighbour sees it
        # unseen and disagreeing pixels count as 0 over the whole view: a scale that throws the
        # view out of its neighbours' photos scores low, not the mean of the few pixels left
        per_view[view] = agreement.clamp_min(0).flatten(1).mean(1).double().cpu()
        compared.append(view)
    total = per_view[taking_part].mean(0)
    best = int(total.argmax())
    contrast = float(total[best] - total.median())
    if not contrast >= MIN_CONTRAST:
        return ScaleSweep(None, float(total[best]), contrast, len(candidates))
    scale = _refined(candidates, total, best)
    return ScaleSweep(scale, float(total[best]), contrast, len(candidates),
                      _view_scales(candidates, per_view, best, scale, compared))


def _view_scales(candidates: torch.Tensor, per_view: torch.Tensor, best: int, scale: float,
                 compared: list[int]) -> torch.Tensor:
    """[V] float64 each compared view's own scale: its best candidate within an octave of the
    scene's `best` (refined as the scene's), where it stands MIN_CONTRAST above the view's own
    sweep median; the scene's `scale` elsewhere."""
    scales = torch.full((per_view.shape[0],), scale, dtype=torch.float64)
    low, high = max(0, best - STEPS_PER_OCTAVE), min(len(candidates) - 1, best + STEPS_PER_OCTAVE)
    for view in compared:
        scores = per_view[view]
        own = low + int(scores[low:high + 1].argmax())
        if scores[own] - scores.median() >= MIN_CONTRAST:
            scales[view] = _refined(candidates, scores, own)
    return scales


def _distinct_distances(cameras: Cameras) -> torch.Tensor:
    """[V, V] float64 distances between the cameras' centres; inf between a camera and itself or
    another at its centre (within 1e-9 of the largest distance: a twin of an exposure bracket)."""
    centres = cameras.centers().double().cpu()
    distances = torch.cdist(centres, centres)
    same = distances <= 1e-9 * float(distances.max()) if distances.numel() else distances.bool()
    return distances.masked_fill(same, math.inf)


def _within_budget(depth: torch.Tensor, cameras: Cameras) -> tuple[torch.Tensor, Cameras]:
    """Depth [V, h, w] area-averaged to at most MAX_PIXELS a view (an integer factor), and the
    cameras' intrinsics for it (pixel-corner origin: the focal lengths and principal point scale
    with the size)."""
    height, width = depth.shape[-2:]
    factor = math.ceil(math.sqrt(height * width / MAX_PIXELS))
    if factor <= 1:
        return depth, cameras
    size = (max(1, height // factor), max(1, width // factor))
    smaller = F.interpolate(depth[:, None].double(), size=size, mode="area")[:, 0]
    intrinsics = cameras.intrinsics.double().clone()
    intrinsics[:, 0] *= size[1] / width
    intrinsics[:, 1] *= size[0] / height
    return smaller, Cameras(cameras.extrinsics, intrinsics, cameras.sizes, cameras.names)


def _candidates(depth: torch.Tensor, distances: torch.Tensor, views: list[int]) -> torch.Tensor | None:
    """[J] float64 factors for the depth, evenly spaced in log (module docstring); None with fewer
    than two views at distinct centres (no parallax fixes any scale)."""
    if len(views) < 2:
        return None
    nearest = distances[views][:, views].min(dim=1).values
    nearest = nearest[torch.isfinite(nearest)]
    if len(nearest) < 2:
        return None
    spacing = float(nearest.median())
    median_depth = float(depth[views].double().median())
    octaves = math.log2(MAX_DEPTH_RATIO / MIN_DEPTH_RATIO)
    ratios = MIN_DEPTH_RATIO * 2 ** (torch.arange(int(octaves * STEPS_PER_OCTAVE) + 1, dtype=torch.float64) / STEPS_PER_OCTAVE)
    return ratios * spacing / median_depth


def _refined(candidates: torch.Tensor, total: torch.Tensor, best: int) -> float:
    """The best candidate moved to the vertex of the parabola through its score and its two
    neighbours' in log scale (within half a step); the candidate itself at either end."""
    if best == 0 or best == len(candidates) - 1:
        return float(candidates[best])
    below, at, above = (float(total[best + shift]) for shift in (-1, 0, 1))
    curvature = below - 2 * at + above
    vertex = min(max(0.5 * (below - above) / curvature, -0.5), 0.5) if curvature < -1e-12 else 0.0
    step = math.log(float(candidates[1] / candidates[0]))
    return float(candidates[best]) * math.exp(vertex * step)
