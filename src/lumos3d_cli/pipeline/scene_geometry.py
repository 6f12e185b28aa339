"""Where a restored scene's cameras and depth come from.

Sources: "network" (the network's own cameras and depth: one forward pass, nothing else), "sfm"
(structure-from-motion with pycolmap on the photos after a blind brightening curve; the network's
depth aligned to its sparse points), "auto" (sfm when it registers most views, else network with
a warning), and given poses (a transforms.json or COLMAP model: cameras known, structure-from-
motion — when it works — only supplies the points the depth is aligned to).

`register_views` runs before the network (so that views without a camera can be sent through the
network), `place_views` after it.

Cameras are in pixels of each photo at its own size; the network sees the photos in one working
tensor (photos of other sizes stretched to it), so its cameras are mapped through each photo's
stretch (anisotropic intrinsics: the geometry stays exact).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError, listed
from lumos3d_cli.eval.metrics import auto_gamma
from lumos3d_cli.geometry.confirmed_depth import confirmed_pixels
from lumos3d_cli.geometry.consistency import depth_consistency
from lumos3d_cli.geometry.depth_alignment import MIN_POINTS, align_depth
from lumos3d_cli.geometry.depth_correction import GRID as DEPTH_CORRECTION_GRID
from lumos3d_cli.geometry.depth_correction import correct_depth
from lumos3d_cli.geometry.field_of_view import FALLBACK_FOV_DEGREES, FOCAL_DISAGREEMENT, focal_ratio, implausible_views
from lumos3d_cli.geometry.given_poses import centred_if_far, read_given_poses
from lumos3d_cli.geometry.photo_consistency import sweep_depth
from lumos3d_cli.geometry.scale_sweep import sweep_depth_scale
from lumos3d_cli.geometry.sweep_settings import DepthSweepSettings
from lumos3d_cli.geometry.colmap_run import SFM_LONG_SIDE, ColmapRun, matching_threads
from lumos3d_cli.geometry.sfm import Registration, register_photos
from lumos3d_cli.geometry.similarity import (
    fill_unregistered_views,
    fit_camera_similarity,
)
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.sparse_points import SparsePoints
from lumos3d_cli.pipeline.choices import GEOMETRY_SOURCES
from lumos3d_cli.pipeline.network_pass import NetworkPass
from lumos3d_cli.pipeline.progress import JobProgress

logger = logging.getLogger(__name__)

# auto uses structure-from-motion when it registers at least this share of the photos (and two):
# the others are placed with the network's cameras, in its frame.
AUTO_MIN_REGISTERED_SHARE = 0.5
# Structure-from-motion's points carried onto given poses that reproject this share of the photos'
# longer side or more from where the given cameras see them: poses that do not belong to the photos
POSE_DISAGREEMENT = 0.1
BRIGHTENING = "auto-gamma (blind tone curve to a mean of 0.45)"


def check_geometry_source(geometry: str) -> None:
    if geometry not in GEOMETRY_SOURCES:
        raise InputError(f"{geometry!r}: use one of {', '.join(GEOMETRY_SOURCES)}", parameter="geometry")


@dataclass
class ViewRegistration:
    """Cameras known before the network runs: `source` ("sfm", "poses" or "network"), each
    photo's own (width, height), the cameras of the views that have one (at their photos' sizes;
    `known` [V] bool says which), and the structure-from-motion result behind them (None when it
    did not run). `origin` [3] float64: where given poses far from their frame's origin were moved
    from (the cameras are in the frame centred there; `centred_if_far`), else None."""

    requested: str
    sizes: list[tuple[int, int]]
    source: str
    known: torch.Tensor
    cameras: Cameras | None
    sfm: Registration | None
    seconds: dict[str, float] = field(default_factory=dict)
    brightening: str | None = None
    origin: torch.Tensor | None = None

    @property
    def fell_back_to_network(self) -> bool:
        """Whether the network's cameras place every view because structure-from-motion, which
        ran, could not (`auto`'s fallback)."""
        return self.source == "network" and self.sfm is not None

    def views_needing_network(self) -> list[int]:
        """Views the network must see because only it can place them."""
        if self.source == "network":
            return []
        return [int(i) for i in torch.nonzero(~self.known).flatten()]


def _structure_from_motion(images: torch.Tensor, names: list[str], sizes: list[tuple[int, int]],
                           progress: JobProgress, long_side: int | None, run: ColmapRun | None = None) -> Registration:
    """images: the photos already brightened (`Brightened`); sizes: each photo's own size;
    long_side: the longest side SfM sees (`register_photos`); run: COLMAP's run on them at
    `long_side` already made (None: run it here)."""
    progress.start("structure from motion", 1)
    threads = matching_threads(len(names))
    registration = register_photos(images, names, long_side=long_side, threads=threads, sizes=sizes, run=run)
    if registration.registered_count < len(names) and long_side is not None and long_side < SFM_LONG_SIDE:
        # Smaller photos hold fewer features: where some view did not register at the reduced
        # size, the default size gets its chance, and the model that places more views is kept.
        retry = register_photos(images, names, long_side=SFM_LONG_SIDE, threads=threads, sizes=sizes)
        logger.info("structure-from-motion at %d px placed %d of %d views; at %d px %d",
                    long_side, registration.registered_count, len(names), SFM_LONG_SIDE, retry.registered_count)
        if retry.registered_count > registration.registered_count:
            registration = retry
    progress.advance("structure from motion")
    return registration


def _warn_if_not_one_model(registration: Registration | None) -> None:
    """A warning where structure-from-motion's model is used although it could not join the photos
    into one (where it is not used, the fallback's warning says so)."""
    if registration is not None and not registration.failed and not registration.looks_like_one_scene:
        logger.warning("structure-from-motion could not join the photos into one model: %s", registration.describe())


def _fields_of_view(names: Sequence[str], degrees: dict[int, float]) -> str:
    """'1.JPG 0.25 degrees, 2.JPG 0.25 degrees' for a warning (a few of them)."""
    return listed([f"{names[view]} {value:.3g} degrees" for view, value in degrees.items()], 3)


@dataclass
class Brightened:
    """The photos as structure-from-motion sees them: images [V, 3, H, W] and how they were made
    (the model's restoration, or a blind tone curve). The photos are dark (or washed out); SIFT
    finds far more features on restored ones."""

    images: torch.Tensor
    method: str

    @staticmethod
    def blind(photos: torch.Tensor) -> Brightened:
        return Brightened(auto_gamma(photos), BRIGHTENING)


def register_views(
    images: torch.Tensor, names: list[str], geometry: str, poses: Path | str | None, progress: JobProgress,
    brightened: Brightened | None = None, sizes: Sequence[tuple[int, int]] | None = None,
    sfm_long_side: int | None = SFM_LONG_SIDE, blind_run: Callable[[], ColmapRun] | None = None,
) -> ViewRegistration:
    """images [V, 3, H, W] (the photos in the working tensor) -> the cameras known before the
    network runs. `brightened`: the photos as SfM should see them (default: the blind tone
    curve); `sizes`: each photo's own (width, height) before it was stretched into `images`
    (None: the tensor's size); `sfm_long_side`: the longest side structure-from-motion sees each
    photo at (None: its own size); `blind_run`: gives COLMAP's run on the blind tone curve at
    `sfm_long_side`, already started (`pipeline.early_registration`; used when `brightened` is
    None and no `poses` are given)."""
    check_geometry_source(geometry)
    brightened = brightened if brightened is not None else Brightened.blind(images)
    images = brightened.images
    count = len(names)
    sizes = list(sizes) if sizes is not None else [(int(images.shape[-1]), int(images.shape[-2]))] * count
    started = time.perf_counter()
    if poses is not None:
        given, origin = centred_if_far(read_given_poses(poses, names, sizes))
        if origin is not None:
            logger.warning("%s: the cameras lie %.3g units from the origin, beyond what float32 positions hold; the "
                           "scene and its cameras are written centred on them (add summary.json's geometry.poses_origin "
                           "to their positions to place them in the poses' frame)", poses, float(origin.norm()))
        odd = implausible_views(given.intrinsics, given.sizes)
        if odd:  # a telescope or a fisheye may be meant; a focal length in the wrong unit more likely
            logger.warning("%s: %d view(s) have a field of view no ordinary lens has (%s); if the focal lengths are "
                           "in another unit than pixels of the photos, the scene will be empty or blurred", poses,
                           len(odd), _fields_of_view(names, odd))
        sfm = _structure_from_motion(images, names, sizes, progress, sfm_long_side) if geometry != "network" and count > 1 else None
        _warn_if_not_one_model(sfm)
        return ViewRegistration(geometry, sizes, "poses", torch.ones(count, dtype=torch.bool), given, sfm,
                                {"sfm": time.perf_counter() - started}, brightened.method, origin)
    if geometry == "network":
        return ViewRegistration(geometry, sizes, "network", torch.zeros(count, dtype=torch.bool), None, None)
    if count < 2:
        if geometry == "sfm":
            raise InputError("sfm: structure-from-motion needs at least two photos; use the network's cameras (--geometry network)",
                             parameter="geometry")
        return ViewRegistration(geometry, sizes, "network", torch.zeros(count, dtype=torch.bool), None, None)
    run = blind_run() if blind_run is not None and brightened.method == BRIGHTENING else None
    registration = _structure_from_motion(images, names, sizes, progress, sfm_long_side, run)
    seconds = {"sfm": time.perf_counter() - started}
    outcome = registration.describe()
    # a model of few features can settle on a focal length no lens has (tens of thousands of pixels
    # for a photo of hundreds): such a view is a blur, and is placed as one that did not register
    # (one such view of British Museum's 10 sent all 10 to the network's cameras, every view ghosted)
    odd = implausible_views(registration.cameras.intrinsics, registration.cameras.sizes)
    if odd:
        odd_names = _fields_of_view(registration.cameras.names, odd)
        registration = registration.without_views([registration.registered_indices[row] for row in odd])
        outcome = f"gave {len(odd)} view(s) a field of view no lens has ({odd_names})"
    if registration.registered_count >= max(2, AUTO_MIN_REGISTERED_SHARE * count):
        _warn_if_not_one_model(registration)
        if odd:
            logger.warning("structure-from-motion %s: placed as views it did not register", outcome)
        return ViewRegistration(geometry, sizes, "sfm", registration.registered.clone(), registration.cameras,
                                registration, seconds, brightened.method)
    if odd:
        outcome += f", leaving {registration.registered_count} of {count} registered"
    if geometry == "sfm":
        raise InputError(f"sfm: structure-from-motion {outcome}; use the network's cameras (--geometry network) or give "
                         "--poses", parameter="geometry")
    logger.warning("structure-from-motion %s; using the network's cameras instead, which place the views at nearly one "
                   "pose: the scene is a ghosted overlay of them. For a 3D scene give --poses or photos that overlap more",
                   outcome)
    return ViewRegistration(geometry, sizes, "network", torch.zeros(count, dtype=torch.bool), None, registration,
                            seconds, brightened.method)


@dataclass
class SceneGeometry:
    """The cameras and depth a scene is built from.

    cameras: one per view that can be rendered (at its photo's own size, names set); network_extrinsics
    [S, 3, 4], network_intrinsics [S, 3, 3] (network pixels) and depth [S, h, w] of the S views
    the network saw, in the scene's frame; points: the sparse structure (empty without SfM);
    `report` the figures summary.json records; fuse_pixels [S, h, w] bool: the pixels whose depth
    the neighbouring views do not contradict (None: all).
    """

    source: str
    cameras: Cameras
    network_extrinsics: torch.Tensor
    network_intrinsics: torch.Tensor
    depth: torch.Tensor
    points: SparsePoints
    report: dict
    fuse_pixels: torch.Tensor | None = None

    def summary(self) -> dict:
        return {"source": self.source, **self.report}


def _photo_cameras(network: NetworkPass, names: list[str], sizes: list[tuple[int, int]]) -> Cameras:
    """The network's own cameras of the selected views `names`, at their photos' own `sizes`."""
    return network.network_cameras(names).rescaled_to(sizes)


def _to_network(network: NetworkPass, cameras: Cameras) -> Cameras:
    """Cameras at their photos' own sizes -> the same cameras in network pixels (through the
    working tensor the network's images were made from)."""
    return network.to_network(cameras.rescaled(*network.prepared.original_size))


def _warn_of_replaced_cameras(network: NetworkPass, used: torch.Tensor) -> None:
    """A warning when the network's cameras are used for views `used` [S] bool whose predicted
    camera no lens has was replaced (`plausible_intrinsics`): not where structure-from-motion or
    given poses place those views, which makes the network's cameras irrelevant."""
    if network.replaced_cameras is None or not bool((network.replaced_cameras & used).any()):
        return
    replaced, count = int(network.replaced_cameras.sum()), len(used)
    # one photo has no structure-from-motion, and its restored view does not depend on its camera
    advice = "" if count == 1 else " (give --poses or use structure-from-motion for exact cameras)"
    logger.warning("the network predicted a camera no lens has (%s) for %d of %d view(s); using square pixels there, at "
                   "the longer side's field of view where it is plausible, else %g degrees%s",
                   network.replaced_fields_of_view, replaced, count, FALLBACK_FOV_DEGREES, advice)


def _network_geometry(registration: ViewRegistration, network: NetworkPass, selected: list[int],
                      names: list[str]) -> SceneGeometry:
    _warn_of_replaced_cameras(network, torch.ones(len(selected), dtype=torch.bool))
    cameras = _photo_cameras(network, names, [registration.sizes[i] for i in selected])
    prediction = network.prediction
    report = {"requested": registration.requested, "registered_views": 0, "brightening": None, "depth_sweep": None}
    if registration.sfm is not None:
        report["sfm_attempt"] = registration.sfm.describe()
    return SceneGeometry("network", cameras, prediction.extrinsics[0].double().cpu(),
                         prediction.intrinsics[0].double().cpu(), prediction.depth[0].cpu(), SparsePoints.empty(),
                         report)


def _points_in_frame(registration: ViewRegistration) -> tuple[SparsePoints, float | None]:
    """The sparse points in the frame of the registration's cameras, and their mean reprojection
    error there (px; None without structure-from-motion): SfM's own, or carried onto the given
    poses by the similarity between SfM's cameras and the given ones, their errors then measured
    against the given cameras (SfM's own would describe cameras that are not written)."""
    sfm = registration.sfm
    if sfm is None or sfm.failed:
        return SparsePoints.empty(), sfm.reprojection_error if sfm is not None else None
    if registration.source != "poses":
        return sfm.points, sfm.reprojection_error
    similarity = fit_camera_similarity(sfm.cameras, registration.cameras[sfm.registered_indices])
    return replace(sfm.points, xyz=similarity.apply(sfm.points.xyz)).reprojected(registration.cameras)


def _points_of_views(points: SparsePoints, views: list[int]) -> SparsePoints:
    """The observations of `views` (indices into the photos), re-indexed to positions in `views`."""
    position = torch.full((int(points.view.max()) + 1 if len(points.view) else 1,), -1, dtype=torch.int64)
    known = [v for v in views if v < position.shape[0]]
    position[known] = torch.tensor([views.index(v) for v in known], dtype=torch.int64)
    keep = position[points.view] >= 0 if len(points.view) else torch.zeros(0, dtype=torch.bool)
    return replace(points, view=position[points.view[keep]], point=points.point[keep], pixel=points.pixel[keep])


def _median(values: torch.Tensor) -> float | None:
    finite = values[torch.isfinite(values)]
    return round(float(finite.median()), 4) if len(finite) else None


def _aligned_depth(
    network: NetworkPass, selected: list[int], network_cameras: Cameras, points: SparsePoints, selected_names: list[str],
    selected_cameras: Cameras, images: torch.Tensor | None, fused: Sequence[bool] | None, given_cameras: bool,
) -> tuple[torch.Tensor, dict]:
    """The network's depth [S, h, w] of the selected views in the registered frame, and how it was
    aligned: per view to the sparse points it observes (a scale and shift, then a smooth
    correction: `geometry.depth_correction`), or — with no points to align to (given poses without
    structure-from-motion, or where it failed or left too few points) — by the scale the selected
    views' photos `images` [S, 3, H, W] agree on (`geometry.scale_sweep`: the scene's, then each
    view's own near it, among the views `fused` marks), and where they agree on none, by the
    scale of the similarity between the network's
    cameras and the registered ones (with a warning: the bundled models' cameras make it a poor
    one). With `given_cameras` (exact, every view's), the photos' scale is also taken where the
    points reach fewer than half the views: the others would take the median alignment of the few
    (on 8 of buu's dark photos, 3 views with points: every view a ghosted double)."""
    on_device = network.prediction.depth[0].detach()  # the scale sweep's, where the network ran
    depth = on_device.cpu().double()
    if len(points) >= MIN_POINTS:
        observed = _points_of_views(points, selected)
        try:
            alignment = align_depth(depth, network_cameras, observed)
        except InputError as error:
            logger.warning("%s; the depth takes one scale for the whole scene instead", error)
        else:
            fitted = int(alignment.fitted.sum())
            swept = (sweep_depth_scale(on_device, network_cameras, images, fused)
                     if given_cameras and images is not None and 2 * fitted < len(selected) else None)
            if swept is not None and swept.scale is not None:
                logger.info("sparse points reach %d of %d views: the depth takes the scale the photos agree on", fitted,
                            len(selected))
                return depth * swept.view_scales[:, None, None], {**swept.summary(), "views": len(selected),
                                                                  "points_fitted_views": fitted}
            correction = correct_depth(alignment.depth, network_cameras, observed)
            return correction.depth, {
                "form": alignment.form, "fitted_views": int(alignment.fitted.sum()), "views": len(selected),
                "scale_only_views": int(alignment.scale_only.sum()),
                "median_relative_residual": round(alignment.median_residual(), 4),
                "points_per_view": alignment.points.tolist(),
                "smooth_correction": {
                    "grid": list(DEPTH_CORRECTION_GRID), "corrected_views": int(correction.corrected.sum()),
                    "median_log_residual_before": _median(correction.residual_before),
                    "median_log_residual_after": _median(correction.residual_after),
                },
            }
    swept = sweep_depth_scale(on_device, network_cameras, images, fused) if images is not None else None
    if swept is not None and swept.scale is not None:
        return depth * swept.view_scales[:, None, None], {**swept.summary(), "views": len(selected)}
    similarity = fit_camera_similarity(network.network_cameras(selected_names), selected_cameras)
    logger.warning("no sparse points to align the network's depth to, and the photos agree on no scale for it; it is "
                   "scaled by the similarity between the network's cameras and the registered ones, which can put the "
                   "scene far off (blurred, ghosted views): let structure-from-motion run (--geometry auto) or give "
                   "more photos")
    return depth * similarity.scale, {"form": "camera similarity scale", "scale": similarity.scale, "views": len(selected),
                                      **({"photo_consistency_contrast": round(swept.contrast, 4)} if swept else {})}


def _warn_of_poses_the_points_contradict(registration: ViewRegistration, reprojection_error: float | None) -> None:
    """A warning when structure-from-motion's points, carried onto the given poses, land far from
    where the given cameras see them (POSE_DISAGREEMENT of the photos' longer side or more; from 3
    registered views: 2 fix the carrying similarity too loosely to tell): the poses of another
    scene, or of photos whose names were swapped, built a collage with exit 0 and no word (8 of
    buu's photos with permuted poses: 269 px, against 7 px with their own). Structure-from-motion
    placing few dark photos wrongly looks the same (8 of buu's in `fast`, their own poses: 498 px;
    the photos' own scale is taken there, `_aligned_depth`): the warning names both."""
    sfm = registration.sfm
    if (registration.source != "poses" or reprojection_error is None or sfm is None
            or len(sfm.registered_indices) < 3):
        return
    side = max(max(size) for size in registration.sizes)
    if reprojection_error >= POSE_DISAGREEMENT * side:
        logger.warning("structure-from-motion's points land %.0f px from where the given cameras see them (photos of %d "
                       "px): either the poses do not belong to these photos (another scene, or names swapped; check "
                       "--poses), or structure-from-motion placed the photos wrongly (few or dark photos)",
                       reprojection_error, side)


def _warn_of_disagreeing_focal_lengths(network_cameras: Cameras, network: NetworkPass, registered: torch.Tensor) -> None:
    """A warning when structure-from-motion's focal lengths of the network's views (in network
    pixels) and the network's own differ by more than FOCAL_DISAGREEMENT: on few photos the
    former can settle on a wrong one that still reprojects its points well. Compared on the views
    structure-from-motion registered (`registered` [S] bool) whose predicted camera the network
    kept (a replaced one is a fallback lens, not a prediction)."""
    compared = registered.clone()
    if network.replaced_cameras is not None:
        compared &= ~network.replaced_cameras
    if not bool(compared.any()):
        return
    predicted = network.prediction.intrinsics[0].detach().double().cpu()[compared]
    ratio = focal_ratio(network_cameras.intrinsics.double()[compared], predicted)
    if 1 / FOCAL_DISAGREEMENT <= ratio <= FOCAL_DISAGREEMENT:
        return
    logger.warning("structure-from-motion's focal lengths are %.1fx the network's for these photos: one of them is wrong "
                   "(on few photos structure-from-motion can settle on a wrong one, and the network's cameras are rough); "
                   "if the views look stretched or blurred, add photos or give --poses", ratio)


def place_views(
    registration: ViewRegistration, network: NetworkPass, selected: list[int], names: list[str],
    images: torch.Tensor | None = None, sweep: DepthSweepSettings | None = None,
    fused: Sequence[bool] | None = None,
) -> SceneGeometry:
    """Combine the registration with the network pass over the `selected` views (indices into
    `names`): every view gets a camera in one frame, and the network's depth of the selected views
    is aligned to the sparse points. With `sweep` and `images` [S, 3, H, W] (the selected views'
    photos, restored or not: the sweep's score ignores gain and offset), registered depth is then
    refined where the neighbouring photos agree (`geometry.photo_consistency`), comparing each
    view only with the views `fused` [S] marks, and sweeping only those (None: all; evaluation's
    held-out views are neither compared with nor swept). Network geometry keeps the network's depth."""
    selected_names = [names[i] for i in selected]
    if registration.source == "network":
        return _network_geometry(registration, network, selected, selected_names)
    known = registration.known
    row_of_view = {view: row for row, view in enumerate(torch.nonzero(known).flatten().tolist())}
    known_selected = known[selected]
    selected_rows = [row_of_view[view] for view in selected if bool(known[view])]
    if bool(known_selected.all()):
        selected_cameras = registration.cameras[selected_rows]
    else:
        if len(selected_rows) < 2:
            raise InputError(f"only {len(selected_rows)} of the network's views were registered; 2 are needed to place "
                             "the others", parameter="geometry")
        # The network's cameras of views SfM could not place, carried into the SfM frame by the
        # similarity between the network's and SfM's cameras of the views both placed.
        selected_cameras = fill_unregistered_views(
            registration.cameras[selected_rows], known_selected,
            _photo_cameras(network, selected_names, [registration.sizes[i] for i in selected]))
        unplaced = [names[view] for view in selected if not bool(known[view])]
        _warn_of_replaced_cameras(network, ~known_selected.cpu())
        logger.warning("%d view(s) not registered by structure-from-motion were placed with the network's cameras: %s",
                       len(unplaced), ", ".join(unplaced))
    position_of_view = {view: position for position, view in enumerate(selected)}
    parts = []
    for view in range(len(names)):
        if view in position_of_view:
            parts.append(selected_cameras[position_of_view[view]])
        elif bool(known[view]):
            parts.append(registration.cameras[row_of_view[view]])
    cameras = Cameras.concatenate(parts)
    cameras = Cameras(cameras.extrinsics.double(), cameras.intrinsics.double(), cameras.sizes,
                      [name for view, name in enumerate(names) if view in position_of_view or bool(known[view])])
    network_cameras = _to_network(network, selected_cameras)
    if registration.source == "sfm":
        _warn_of_disagreeing_focal_lengths(network_cameras, network, known_selected.cpu())
    points, reprojection_error = _points_in_frame(registration)
    _warn_of_poses_the_points_contradict(registration, reprojection_error)
    depth, alignment_report = _aligned_depth(network, selected, network_cameras, points, selected_names, selected_cameras,
                                             images, fused, registration.source == "poses")
    sweep_report = None
    if sweep is not None and images is not None and len(selected) > 1:
        swept = sweep_depth(depth, network_cameras, images, sweep, fused)
        depth, sweep_report = swept.depth, swept.summary(sweep)
    # float32 is ample for a 2 % test (the figure is reported, not used)
    consistency = depth_consistency(depth.float(), network_cameras.to(torch.float32)) if len(selected) > 1 else None
    fuse_pixels = confirmed_pixels(depth, network_cameras)
    sfm = registration.sfm
    report = {
        "requested": registration.requested,
        "registered_views": int(known.sum()) if registration.source == "sfm" else None,
        "views": len(names),
        "brightening": registration.brightening if sfm is not None else None,
        "reprojection_error_px": reprojection_error,
        "sparse_points": len(points),
        "models": sfm.model_sizes if sfm is not None else None,
        "matching": sfm.matching if sfm is not None else None,
        "sfm_size": list(sfm.sfm_size) if sfm is not None else None,
        "depth_alignment": alignment_report,
        "depth_sweep": sweep_report,
        "depth_consistency": round(consistency.share, 4) if consistency is not None else None,
        "pixels_kept": round(float(fuse_pixels.float().mean()), 4),
        "poses_origin": registration.origin.tolist() if registration.origin is not None else None,
    }
    return SceneGeometry(registration.source, cameras, network_cameras.extrinsics, network_cameras.intrinsics,
                         depth, points, report, fuse_pixels)
