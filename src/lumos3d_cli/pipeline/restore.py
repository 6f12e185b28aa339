"""The restore job: degraded photos -> registered cameras, one forward pass of the network, fused
Gaussians (the stages of pipeline/scene_stages.py), and every input view rendered back at its own
camera and its photo's own size (one photo alone: that photo restored in 2D).

`restore` runs the whole job from files (what `lumos3d restore` does); `restore_scene` runs it on
loaded images and a loaded model; `pipeline.restore_outputs.write_restored_scene` writes it."""

from __future__ import annotations

import logging
import resource
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import torch

from lumos3d_cli.checks import require_unit_range
from lumos3d_cli.data.degradations import MODES
from lumos3d_cli.errors import InputError, NonFiniteError, listed
from lumos3d_cli.geometry.given_poses import read_given_poses
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.file_digest import file_sha256
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.io.images import ImageBatch, load_images
from lumos3d_cli.io.scene_photos import list_photos
from lumos3d_cli.model.appearance.photo_restoration import frames_without_content
from lumos3d_cli.model.bundled_models import resolve_checkpoint
from lumos3d_cli.model.lumos3d import GaussianCounts, Lumos3D
from lumos3d_cli.pipeline.choices import DEFAULT_RESTORE_PRESET
from lumos3d_cli.pipeline.early_registration import EarlyRegistration
from lumos3d_cli.pipeline.model_loading import load_restoration_model
from lumos3d_cli.pipeline.presets import RestorePreset, check_max_views, get_restore_preset
from lumos3d_cli.pipeline.progress import JobProgress, SilentProgress
from lumos3d_cli.pipeline.quality import QualityMeter, load_references, mean_metrics
from lumos3d_cli.pipeline.restore_paths import check_lpips_weights
from lumos3d_cli.pipeline.scene_geometry import SceneGeometry, check_geometry_source
from lumos3d_cli.pipeline.scene_stages import build_scene
from lumos3d_cli.render.constants import MAX_IMAGE_SIDE
from lumos3d_cli.render.hole_filling import render_shown
from lumos3d_cli.render.view_threads import map_views

logger = logging.getLogger(__name__)


@dataclass
class RestoredScene:
    """One restored scene.

    gaussians: the fused scene (world frame of the geometry source); cameras: one per restored
    view at its photo's own size; restored: per view [3, H, W], the render at its camera (photos
    of different sizes give views of different sizes; a one-photo scene: the photo restored in
    2D); inputs: per view [3, H, W] the photo; names of the views; selected: indices (into the inputs) of the views the network saw;
    geometry: where the cameras came from and how well depth agrees; metrics/references (per
    view [3, H, W]) when reference photos were given; timings in seconds per stage.
    """

    gaussians: Gaussians
    cameras: Cameras
    restored: list[torch.Tensor]
    inputs: list[torch.Tensor]
    names: list[str]
    input_paths: list[Path]
    selected: list[int]
    counts: GaussianCounts
    network_size: tuple[int, int]
    geometry: SceneGeometry
    preset: str
    mode: str
    device: str = "cpu"
    checkpoint: dict = field(default_factory=dict)
    metrics: dict | None = None
    references: list[torch.Tensor] | None = None
    timings: dict[str, float] = field(default_factory=dict)
    refinement: dict | None = None  # the refinement's steps, loss curve, SH degree (None: not refined)
    budget: dict | None = None  # the Gaussian budget the scene got (SceneJob.budget)
    exposure: dict | None = None  # the exposure prior's strength and gain (SceneJob.exposure)
    uncovered: dict | None = None  # the views' pixels no Gaussian covered and whether they were filled (None: not rendered)
    # "render": the scene at each camera; "photo restoration": the photos restored in 2D; "render and
    # photo restoration": the views no geometry placed restored in 2D, the others rendered
    view_source: str = "render"
    fill_unobserved: bool = True  # how the scene's renders are shown (its views, its video): filled, or over black
    denoising: dict | None = None  # 2D-restored views' measured noise and whether it was removed (None: rendered views)
    # what the job read, as given (the photos' folder or files, poses, references, checkpoint):
    # write_restored_scene keeps the outputs clear of them, as `lumos3d restore` does
    read_from: list[Path] = field(default_factory=list)

    def summary(self, scene_path: Path | str | None = None, ply_bytes: int | None = None) -> dict:
        """The JSON summary of the run (summary.json); `ply_bytes`: the size of the written scene."""
        return {
            "scene": str(scene_path) if scene_path is not None else None,
            "inputs": len(self.input_paths), "views": self.names,
            "input_paths": [str(path.resolve()) for path in self.input_paths],  # absolute: the viewer finds them
            "network_views": [self.input_paths[i].name for i in self.selected],
            "network_size": list(self.network_size), "preset": self.preset, "mode": self.mode, "device": self.device,
            "checkpoint": self.checkpoint, "geometry": self.geometry.summary(),
            "gaussians": {"pixel": self.counts.pixels, "voxels": self.counts.voxels,
                          "pruned": self.counts.pruned, "kept": len(self.gaussians), "budget": self.budget,
                          "ply_mib": None if ply_bytes is None else round(ply_bytes / 2**20, 3)},
            "seconds": {name: round(value, 3) for name, value in self.timings.items()},
            "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
            "refinement": self.refinement, "exposure_prior": self.exposure, "uncovered": self.uncovered,
            "restored_views": self.view_source, "photo_denoising": self.denoising,
            "metrics": self.metrics,
        }


@dataclass
class RenderedViews:
    """images: per camera [3, H, W] at its own size; unobserved: per camera the fraction of its
    pixels no Gaussian covered (rendered alpha below render.hole_filling.OBSERVED_ALPHA); filled:
    whether those were filled by inpainting (else they show the black background)."""

    images: list[torch.Tensor]
    unobserved: list[float]
    filled: bool

    def summary(self) -> dict:
        """summary.json's / metrics.json's account of the uncovered pixels."""
        return {"filled": self.filled, "unobserved_fraction": [round(value, 5) for value in self.unobserved]}


def render_views(gaussians: Gaussians, cameras: Cameras, sh_degree: int | None,
                 progress: JobProgress | None = None, fill: bool = False) -> RenderedViews:
    """Every camera rendered at its own size, one view per thread on the CPU
    (`render.view_threads`; bounded memory at full resolution); with `fill` the pixels no Gaussian
    covers are filled (render.hole_filling)."""
    degree = gaussians.sh_degree if sh_degree is None else min(sh_degree, gaussians.sh_degree)

    def view(index: int) -> tuple[torch.Tensor, float]:
        shown = render_shown(gaussians, cameras[index], fill, sh_degree=degree)
        return shown.image.cpu(), shown.unobserved

    images, unobserved = [], []
    for image, fraction in map_views(view, len(cameras), gaussians.means.device):
        images.append(image)
        unobserved.append(fraction)
        if progress is not None:
            progress.advance("render views")
    return RenderedViews(images, unobserved, fill)


def restore_scene(
    batch: ImageBatch, model: Lumos3D, preset: RestorePreset | str, geometry: str = "auto", poses: Path | str | None = None,
    max_views: int | None = None, mode: str = "low-light", progress: JobProgress | None = None,
    early_registration: EarlyRegistration | None = None,
) -> RestoredScene:
    """The job on loaded photos (sRGB in [0, 1]) and a loaded model (`build_scene`, which takes
    structure-from-motion from `early_registration` when it was started before), then every view
    that has a camera rendered at it, at its photo's own size. `preset`: a RestorePreset or a
    preset's name."""
    progress = progress or SilentProgress()
    if isinstance(preset, str):
        preset = get_restore_preset(preset)
    elif not isinstance(preset, RestorePreset):
        raise InputError(f"preset {preset!r}: give a preset's name or a RestorePreset (get_restore_preset)")
    names = [path.name for path in batch.paths]
    finite = torch.isfinite(batch.images).flatten(1).all(dim=1)
    if not bool(finite.all()):  # a batch made in Python: the files' own readers refuse NaN by name
        broken = [str(batch.paths[index]) for index in (~finite).nonzero().flatten().tolist()]
        raise NonFiniteError(f"{listed(broken, 3)}: the photo's pixels hold NaN or Inf; give finite values in [0, 1]")
    if len(names) == 0:
        raise InputError("no photos in the batch; give at least one")
    require_unit_range("photos", batch.images)
    if batch.mixed_sizes:
        odd = [name for name, size in zip(names, batch.original_sizes) if size != batch.size]
        logger.warning("%d of %d photos differ in size from %dx%d (%s): the network sees them stretched to it, their "
                       "cameras and restored views keep each photo's own size and aspect ratio", len(odd), len(names),
                       *batch.size, ", ".join(odd[:5]) + (" ..." if len(odd) > 5 else ""))
    # A photo with nothing in it (all black or all saturated) gives no Gaussian and is fitted by no
    # refinement step: its depth and colours are made up, and fused they laid black or white wedges
    # over the other views. Its view is the photo as it is.
    empty = set().union(*photos_without_content(batch))
    _require_some_content(batch, empty)
    fuse_views = [index not in empty for index in range(len(names))] if empty and len(empty) < len(names) else None
    # one photo with content always among the network's views: a subset of empty ones builds nothing
    required = [fuse_views.index(True)] if fuse_views is not None else []
    built = build_scene(batch.images, names, model, preset, geometry, poses, max_views, mode, progress,
                        required_views=required, fuse_views=fuse_views, sizes=batch.original_sizes,
                        early_registration=early_registration, empty_views=sorted(empty), photo_at_own_size=batch.photo)
    cameras = built.geometry.cameras
    missing = [name for name in names if name not in cameras.names]
    if missing:
        # (after structure-from-motion failed on them, only more views through the network help)
        advice = "raise max_views" + ("" if built.registration.fell_back_to_network else " or use structure-from-motion")
        logger.warning("%d view(s) have no camera and are not restored (the network did not see them; %s): %s",
                       len(missing), advice, ", ".join(missing))
    progress.start("render views", len(cameras))
    started = time.perf_counter()
    in_2d = {names[view] for view in built.views_in_2d}  # one photo, or photos no geometry placed
    if in_2d | {names[view] for view in empty} >= set(cameras.names):  # (an empty photo is shown as it is, below)
        # every view is its photo restored in 2D (scene_stages.photo_restoration): nothing to render
        views = [built.photo_restoration[names.index(name)].clamp(0, 1) if name in in_2d else batch.photo(names.index(name))
                 for name in cameras.names]
        uncovered, view_source = None, "photo restoration"
        progress.advance("render views", len(cameras))
    else:
        # the operator's full-resolution restorations are fused and fitted: their memory (0.15 GB
        # a 12-MP photo) goes before the views are rendered at the photos' size
        built.restored_photos = None
        rendered = render_views(built.gaussians, cameras, preset.sh_degree, progress, fill=preset.fill_unobserved)
        views, uncovered = rendered.images, rendered.summary()
        # a view shown restored in 2D covers its whole photo: no share of it is uncovered
        uncovered["unobserved_fraction"] = [None if name in in_2d else fraction for name, fraction
                                            in zip(cameras.names, uncovered["unobserved_fraction"])]
        view_source = "render and photo restoration" if in_2d else "render"
        bare = [f"{name} ({fraction:.0%})" for name, fraction in zip(cameras.names, rendered.unobserved)
                if fraction > MOSTLY_UNCOVERED and name not in in_2d
                and (fuse_views is None or fuse_views[names.index(name)])]
        if bare:  # a flat colour where the view should be: a cap far too low, or cameras that miss the scene
            logger.warning("%d view(s) are mostly uncovered: no Gaussian covers %s of their pixels; raise max_gaussians "
                           "or check the cameras", len(bare), listed(bare, 3))
        views = [built.photo_restoration[names.index(name)].clamp(0, 1) if name in in_2d else view
                 for view, name in zip(views, cameras.names)]
        built.photo_restoration = None
    if fuse_views is not None:
        views = [view if fuse_views[names.index(name)] else batch.photo(names.index(name))
                 for view, name in zip(views, cameras.names)]
    timings = built.timings | {"render": time.perf_counter() - started}
    inputs = [batch.photo(names.index(name)) for name in cameras.names]
    return RestoredScene(
        built.gaussians.to(device="cpu"), cameras, views, inputs, list(cameras.names), list(batch.paths),
        built.selected, built.counts, built.network_size, built.geometry, preset.name, mode, timings=timings,
        refinement=built.refinement, budget=built.budget, exposure=built.exposure, uncovered=uncovered,
        view_source=view_source, denoising=built.denoising, fill_unobserved=preset.fill_unobserved,
    )


# The share of a restored view's pixels no Gaussian covers beyond which it is warned of: buu's and
# shrub's views have at most 8 % (a held-out view's edge); over half is a view the scene misses.
MOSTLY_UNCOVERED = 0.5

# The photos' mean sRGB level beyond which a mode does not fit them: the development sources' dark
# inputs average 0.03-0.12 and reach 0.27 (a lit night street), their over-exposed ones 0.63-0.92,
# normal-light scenes 0.34-0.55.
DARK_FOR_OVER_EXPOSURE = 0.3
BRIGHT_FOR_LOW_LIGHT = 0.6


def _warn_of_a_mode_the_photos_contradict(batch: ImageBatch, mode: str, empty: set[int]) -> None:
    """A warning when dark photos go through the over-exposure model (it darkens them further) or
    bright ones through the low-light model (it brightens them into white): for the set, when
    every photo contradicts the mode, else naming the photos that do (a flash photo among dark
    ones, a set mixing both exposures: one restoration of the set ruins them). Photos in `empty`
    (all black or white, warned of apart) are left out."""
    levels = {view: float(photo.mean()) for view, photo in enumerate(batch.images) if view not in empty}
    darkens = mode == "over-exposure"
    contrary = [view for view, level in levels.items()
                if (level < DARK_FOR_OVER_EXPOSURE if darkens else level > BRIGHT_FOR_LOW_LIGHT)]
    if not contrary:
        return
    kind, does, other = ("dark", "darkens", "low-light") if darkens else ("bright", "brightens", "over-exposure")
    if len(contrary) == len(levels):
        logger.warning("the photos are %s (mean level %.2f) for the %s mode, which %s; did you mean the %s mode?", kind,
                       sum(levels.values()) / len(levels), mode, does, other)
        return
    shown = ", ".join(f"{batch.paths[view].name} ({levels[view]:.2f})" for view in contrary[:5])
    logger.warning("%d of %d photos are %s for the %s mode, which %s: %s%s; one restoration of the set cannot suit "
                   "both exposures: restore them apart, the %s photos in the %s mode", len(contrary), len(levels),
                   kind, mode, does, shown, " ..." if len(contrary) > 5 else "", kind, other)


def _warn_of_repeated_photos(batch: ImageBatch, empty: set[int]) -> None:
    """A warning naming photos that hold the same image (a copy under another name): one view
    counted twice, and a pair structure-from-motion cannot place (no baseline). Photos in `empty`
    (all black or white, warned of apart) are left out."""
    # equal images have equal sums (the same reduction of the same values): compared only then;
    # one view at a time, in the photos' own precision (a float64 copy of a RAW set is gigabytes)
    sums = [float(view.sum()) for view in batch.images]
    seen: dict[float, list[int]] = {}
    for view, total in enumerate(sums):
        if view in empty:
            continue
        copy_of = next((other for other in seen.get(total, []) if torch.equal(batch.images[other], batch.images[view])), None)
        if copy_of is not None:
            logger.warning("%s holds the same image as %s: the view counts twice, and no camera can be placed from the "
                           "pair; leave one out", batch.paths[view].name, batch.paths[copy_of].name)
        seen.setdefault(total, []).append(view)


def photos_without_content(batch: ImageBatch) -> tuple[list[int], list[int]]:
    """(indices of the all-black photos, of the all-saturated ones), each judged at its own size
    (`frames_without_content`: a photo stretched to the batch's size gains levels and passed for
    an image)."""
    black, saturated = [], []
    for index in range(len(batch.paths)):
        found = frames_without_content(batch.photo(index)[None])
        black += [index] * len(found[0])
        saturated += [index] * len(found[1])
    return black, saturated


def _require_some_content(batch: ImageBatch, empty: set[int]) -> None:
    """InputError when every photo of `batch` is in `empty` (all black or all saturated): one such
    photo alone too, whose scene would be made up from a blank frame."""
    if len(empty) == len(batch.paths):
        every = "every photo is" if len(batch.paths) > 1 else "the photo is"
        raise InputError(f"{listed([str(path) for path in batch.paths], 3)}: {every} entirely black or saturated; "
                         "there is nothing to restore: give photos that recorded the scene")


def check_photo_contents(batch: ImageBatch, patch_size: int, mode: str) -> None:
    """InputError naming a photo too small to hold one network patch (`patch_size` pixels a side)
    or too large to render its view (MAX_IMAGE_SIDE);
    a warning naming the photos that are all black or all saturated (nothing to restore there),
    one naming photos that are copies of others, and one when the photos contradict `mode`."""
    names = [path.name for path in batch.paths]
    for path, (width, height) in zip(batch.paths, batch.original_sizes):
        if min(width, height) < patch_size:
            raise InputError(f"{path}: is {width}x{height} pixels, too small for the network (at least {patch_size} "
                             "pixels a side); leave it out")
        if max(width, height) > MAX_IMAGE_SIDE:  # its view is rendered at its own size (render.render)
            raise InputError(f"{path}: is {width}x{height} pixels; lumos3d renders views of at most {MAX_IMAGE_SIDE} "
                             "pixels a side: downscale it")
    black, saturated = photos_without_content(batch)
    _require_some_content(batch, {*black, *saturated})  # before the warnings that would call them "left out"
    _warn_of_repeated_photos(batch, {*black, *saturated})
    _warn_of_a_mode_the_photos_contradict(batch, mode, {*black, *saturated})
    for kind, indices in (("black", black), ("saturated", saturated)):
        if indices:
            logger.warning("%s %s entirely %s: nothing to restore there (%s stay %s, and the scene's restoration is "
                           "predicted and metered without %s)", ", ".join(names[i] for i in indices),
                           "is" if len(indices) == 1 else "are", kind, "its pixels" if len(indices) == 1 else "their pixels",
                           "black" if kind == "black" else "white", "it" if len(indices) == 1 else "them")


def restore(
    photos: Path | str | Sequence[Path | str], mode: str = "low-light", checkpoint: Path | str | None = None,
    preset: str = DEFAULT_RESTORE_PRESET, geometry: str = "auto", poses: Path | str | None = None,
    max_views: int | None = None, device: str = "cpu", reference: Path | str | None = None,
    lpips_weights: Path | str | None = None, progress: JobProgress | None = None, refine_steps: int | None = None,
    max_gaussians: int | None = None, gaussian_grid: float | None = None, exposure_prior: float | None = None,
    fill_unobserved: bool | None = None, denoise_photo: bool | None = None, densify: bool | None = None,
    exposure_key: str | None = None, early_registration: EarlyRegistration | None = None,
    depth_sweep: bool | None = None,
) -> RestoredScene:
    """The whole restore job from files: photos (a folder or files: photos, camera RAW, EXR),
    the bundled model of `mode` or `checkpoint`, and optionally reference photos of the same
    views (same file stems) for PSNR/SSIM/LPIPS. `refine_steps` overrides the preset's
    test-time refinement (0: none), `max_gaussians` caps the scene's Gaussians and
    `gaussian_grid` sets the density of pixel Gaussians (`pipeline.gaussian_grid`),
    `exposure_prior` the strength of the exposure prior (`model.appearance.exposure_prior`) and
    `exposure_key` the key it pulls towards ("content": `model.appearance.exposure_key`, or "fixed"),
    `fill_unobserved` whether pixels no Gaussian covers are filled (`render.hole_filling`),
    `denoise_photo` whether the amplified noise of views restored in 2D (a one-photo restore's;
    photos no geometry places) is removed
    (`model.appearance.amplified_noise`), `densify` whether refinement densifies
    (`refine.densification`), `depth_sweep` whether the registered depth is refined by the
neighbouring photos (`geometry.photo_consistency`). `early_registration`: the photos read and structure-from-motion
    started before torch was imported (`pipeline.early_registration`, as `lumos3d restore` does;
    the caller closes it).
    Write the result with `write_restored_scene`."""
    progress = progress or SilentProgress()
    started = time.perf_counter()
    if mode not in MODES:
        raise InputError(f"{mode!r}: use one of {', '.join(MODES)}", parameter="mode")
    check_max_views(max_views)
    settings = get_restore_preset(preset, refine_steps, max_gaussians, gaussian_grid, exposure_prior, fill_unobserved,
                                  denoise_photo, densify, exposure_key, depth_sweep)
    check_geometry_source(geometry)
    check_lpips_weights(lpips_weights, reference)
    weights = resolve_checkpoint(checkpoint, mode)
    meter = QualityMeter.create(lpips_weights) if reference is not None else None
    timings: dict[str, float] = {}
    stage_started = time.perf_counter()
    paths = list_photos(photos)
    progress.start("load images", len(paths))
    if early_registration is not None:
        if early_registration.paths != paths:
            raise ValueError("the early registration was started for other photos")
        batch = early_registration.photos().batch()
        progress.advance("load images", len(paths))
    else:
        batch = load_images(paths, progress=lambda _: progress.advance("load images"))
    if poses is not None:  # a camera file that does not fit the photos stops the run before the work
        read_given_poses(poses, [path.name for path in paths], batch.original_sizes, warn_on_distortion=False)
    # References are matched and read before the work, so that a missing one stops the run at once.
    references = None if reference is None else dict(zip(
        (path.name for path in paths), load_references(reference, [path.name for path in paths], batch.original_sizes)))
    timings["load"] = time.perf_counter() - stage_started
    stage_started = time.perf_counter()
    model = load_restoration_model(weights, device, mode)
    timings["load_model"] = time.perf_counter() - stage_started
    check_photo_contents(batch, model.architecture.patch_size, mode)
    scene = restore_scene(batch, model, settings, geometry, poses, max_views, mode, progress, early_registration)
    scene.device = device
    scene.checkpoint = {"name": weights.name, "sha256": file_sha256(weights)}
    if reference is not None:
        stage_started = time.perf_counter()
        scene.references = [references[name] for name in scene.names]
        per_view = meter.measure(scene.restored, scene.references)
        scene.metrics = {"views": dict(zip(scene.names, per_view)), "mean": mean_metrics(per_view),
                         "lpips_note": meter.lpips_note}
        timings["metrics"] = time.perf_counter() - stage_started
    scene.timings = timings | scene.timings
    scene.timings["total"] = time.perf_counter() - started
    given = [photos] if isinstance(photos, (str, Path)) else list(photos)
    scene.read_from = [Path(path) for path in (*given, poses, reference, checkpoint, lpips_weights) if path is not None]
    return scene
