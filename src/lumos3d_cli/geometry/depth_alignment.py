"""The network's depth of each view, brought into the registered frame by the sparse points that
view observes: a robust scale and shift per view.

Form: FORM (see DEPTH_FORMS). "depth" fits z_sfm ~ a * d + b; "inverse depth" fits
1 / z_sfm ~ a / d + b. Both minimise relative errors with iteratively reweighted least squares
(Cauchy weights, scale from the median absolute deviation), so a few wrong matches or points on
a depth edge do not pull the fit. The default, inverse depth, was chosen by measurement with the
bundled low-light model (benchmarks/sfm.py, docs/performance.md): median held-out relative
residual (fit on half of each view's points, scored on the other half) and the multi-view
consistency of the aligned depth (share within 2 %):

    scene (SfM on auto-gamma photos)      depth: residual / consistency   inverse depth
    LOM buu low/                          4.8 % / 0.43                    4.5 % / 0.45
    Strecha fountain-P11, darkened        6.1 % / 0.21                    6.8 % / 0.22
    Strecha Herz-Jesus-P8, darkened      10.2 % / 0.31                    8.1 % / 0.35

Inverse depth has the lower residual on two scenes of three and the higher consistency on all.

A view with fewer than MIN_POINTS usable points (or none: a view SfM did not register) takes the
median scale and shift of the fitted views. Where the best affine fit has a scale <= 0 (the
network's depth runs against the points: a near-flat or inverted prediction, as the bundled tiny
model gives on some deep, cluttered scenes, e.g. riverview's warehouse), its relative depths carry nothing the
points can use, so only a scale is fitted (no shift): positive depth of the right size, and the
smooth correction (`geometry.depth_correction`) then bends it towards the points.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.reprojection import inside_view, sample_map
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.sparse_points import SparsePoints

DEPTH_FORMS = ("depth", "inverse depth")
DEFAULT_FORM = "inverse depth"
MIN_POINTS = 16
_IRLS_STEPS = 20
_CAUCHY = 2.385  # 95 % efficiency at the normal distribution
# Aligned depth is kept within [median / _DEPTH_RANGE, median * _DEPTH_RANGE] of its view, so that an
# affine map that crosses zero cannot yield negative or infinite depth.
_DEPTH_RANGE = 1e3


@dataclass
class DepthAlignment:
    """depth [V, h, w] aligned (registered frame); scale, shift [V] (of the chosen form);
    fitted [V] bool: False where the scene's median alignment was used; scale_only [V] bool: the
    affine fit had a scale <= 0 and a scale alone was fitted; points [V] int64 points
    used per view; residual [V] median relative depth error |z - z_sfm| / z_sfm at those points
    after alignment (nan for a view without points); form: "depth" or "inverse depth"."""

    depth: torch.Tensor
    scale: torch.Tensor
    shift: torch.Tensor
    fitted: torch.Tensor
    scale_only: torch.Tensor
    points: torch.Tensor
    residual: torch.Tensor
    form: str

    def median_residual(self) -> float:
        """Median over views with points of their median relative residual (nan if none)."""
        values = self.residual[~torch.isnan(self.residual)]
        return float(values.median()) if len(values) else float("nan")


def sample_depth(depth: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of depth [h, w] at pixels [N, 2] (u, v; origin at the top-left pixel
    corner) -> [N]; outside the image: nan."""
    values = sample_map(depth, pixels[:, 0], pixels[:, 1])
    inside = inside_view(pixels[:, 0], pixels[:, 1], None, depth.shape)
    return torch.where(inside, values, torch.full_like(values, float("nan")))


def view_correspondences(
    depth: torch.Tensor, cameras: Cameras, points: SparsePoints, view: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """(network depth [N], SfM depth [N]) at the points that `view` observes, projected with its
    camera (intrinsics in pixels of the depth map, so any crop or resize is accounted for);
    points behind the camera, outside the image or on non-positive depth are left out."""
    seen = points.point[points.view == view]
    if len(seen) == 0:
        return torch.zeros(0, dtype=torch.float64), torch.zeros(0, dtype=torch.float64)
    pixels, sfm_depth = cameras[view].project(points.xyz[seen].to(cameras.extrinsics.dtype))
    network_depth = sample_depth(depth[view].double(), pixels[0].double())
    keep = (sfm_depth[0] > 0) & (network_depth > 0) & torch.isfinite(network_depth)
    return network_depth[keep], sfm_depth[0, keep].double()


def _forward(values: torch.Tensor, form: str) -> torch.Tensor:
    """Depth -> the quantity the affine model acts on."""
    return values if form == "depth" else 1.0 / values


def fit_scale_shift(source: torch.Tensor, target: torch.Tensor, with_shift: bool = True) -> tuple[float, float]:
    """Robust a, b with target ~ a * source + b, minimising relative errors (a - b*s - t) / t
    by IRLS with Cauchy weights. source, target [N] positive. With (near) constant source the
    shift is undetermined and only a scale is fitted; `with_shift` False fits only a scale (b = 0,
    a > 0)."""
    base = 1.0 / target
    scale, shift = float((target / source).median()), 0.0
    constant = float(source.std()) <= 1e-9 * float(source.abs().mean()) if len(source) > 1 else True
    for _ in range(_IRLS_STEPS):
        relative = (scale * source + shift - target) * base
        spread = max(1.4826 * float(relative.abs().median()), 1e-6)
        weights = base / (1 + (relative / (_CAUCHY * spread)) ** 2).sqrt()  # sqrt: rows of a least-squares system
        if constant or not with_shift:
            scale = float((weights * source * weights * target).sum() / (weights * source).square().sum())
            continue
        system = torch.stack([source * weights, weights], dim=1)
        solution = torch.linalg.lstsq(system, (target * weights)[:, None]).solution[:, 0]
        scale, shift = float(solution[0]), float(solution[1])
    return scale, shift


def _affine(depth: torch.Tensor, scale: float, shift: float, form: str) -> torch.Tensor:
    """The affine map of the form, unclamped: depth [...] -> depth [...]."""
    if form == "depth":
        return scale * depth + shift
    return 1.0 / (scale / depth.clamp_min(1e-12) + shift)


def apply_scale_shift(depth: torch.Tensor, scale: float, shift: float, form: str) -> torch.Tensor:
    """depth [h, w] -> aligned depth [h, w], clamped to _DEPTH_RANGE about its median."""
    aligned = _affine(depth, scale, shift, form)
    valid = aligned[(aligned > 0) & torch.isfinite(aligned)]
    median = float(valid.median()) if len(valid) else float("nan")
    if not median > 0:
        return torch.full_like(depth, float("nan"))
    aligned = torch.where((aligned > 0) & torch.isfinite(aligned), aligned, torch.full_like(aligned, median * _DEPTH_RANGE))
    return aligned.clamp(median / _DEPTH_RANGE, median * _DEPTH_RANGE)


def _relative_residual(aligned: torch.Tensor, target_depth: torch.Tensor) -> float:
    return float(((aligned - target_depth).abs() / target_depth).median()) if len(target_depth) else float("nan")


def align_depth(
    depth: torch.Tensor, cameras: Cameras, points: SparsePoints, form: str = DEFAULT_FORM, min_points: int = MIN_POINTS
) -> DepthAlignment:
    """Align depth [V, h, w] (e.g. the network's) to sparse points.

    cameras: the V views in the registered frame, intrinsics in pixels of the depth maps (for
    photo-resolution cameras pass `cameras.rescaled(w, h)`, or map them as the network's
    preprocessing did); points: the registered sparse points, `view` indexing the V views.
    InputError when no view has `min_points` points (nothing to align to) or for non-finite depth.
    """
    if form not in DEPTH_FORMS:
        raise InputError(f"depth alignment form {form!r}: use one of {', '.join(DEPTH_FORMS)}")
    if depth.dim() != 3 or depth.shape[0] != len(cameras):
        raise InputError(f"depth must be [V, h, w] for {len(cameras)} cameras, got {tuple(depth.shape)}")
    require_finite("depth to align", depth)
    views = depth.shape[0]
    scale = torch.full((views,), float("nan"), dtype=torch.float64)
    shift = torch.zeros(views, dtype=torch.float64)
    fitted = torch.zeros(views, dtype=torch.bool)
    scale_only = torch.zeros(views, dtype=torch.bool)
    used = torch.zeros(views, dtype=torch.int64)
    pairs = []
    for view in range(views):
        network_depth, sfm_depth = view_correspondences(depth, cameras, points, view)
        pairs.append((network_depth, sfm_depth))
        used[view] = len(sfm_depth)
        if len(sfm_depth) < min_points:
            continue
        source, target = _forward(network_depth, form), _forward(sfm_depth, form)
        a, b = fit_scale_shift(source, target)
        if not a > 0:
            a, b = fit_scale_shift(source, target, with_shift=False)
            scale_only[view] = True
        if a > 0:
            scale[view], shift[view], fitted[view] = a, b, True
    if not fitted.any():
        raise InputError(f"depth alignment: no view observes {min_points} sparse points (most: {int(used.max())}); "
                         "the registration is too sparse to place the depth")
    scale[~fitted] = scale[fitted].median()
    shift[~fitted] = shift[fitted].median()
    aligned = torch.stack([apply_scale_shift(depth[v].double(), float(scale[v]), float(shift[v]), form) for v in range(views)])
    require_finite("aligned depth", aligned, "the network's depth has no usable values")
    residual = torch.tensor([
        _relative_residual(_affine(network_depth, float(scale[v]), float(shift[v]), form), sfm_depth)
        for v, (network_depth, sfm_depth) in enumerate(pairs)
    ], dtype=torch.float64)
    return DepthAlignment(aligned.to(depth.dtype), scale, shift, fitted, scale_only, used, residual, form)
