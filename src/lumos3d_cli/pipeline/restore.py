"""The restore job: degraded photos -> registered cameras, one forward pass of the network, fused
Gaussians, and every input view rendered back at its own camera and its photo's own size (one
photo alone: that photo restored in 2D, see `BuiltScene`).

`restore` runs the whole job from files (what `lumos3d restore` does); `restore_scene` runs it on
loaded images and a loaded model; `pipeline.restore_outputs.write_restored_scene` writes it."""

from __future__ import annotations

import logging
import resource
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch

from lumos3d_cli.data.degradations import MODES
from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.given_poses import read_given_poses
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.file_digest import file_sha256
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.io.image_files import list_images
from lumos3d_cli.io.images import ImageBatch, load_images
from lumos3d_cli.model.appearance.footprint import footprint_colours
from lumos3d_cli.model.appearance.gaussian_colours import with_operator_colours
from lumos3d_cli.model.appearance.operator import AppearanceOperator
from lumos3d_cli.model.appearance.photo_restoration import frames_without_content, restore_photos
from lumos3d_cli.model.bundled_models import resolve_checkpoint
from lumos3d_cli.model.lumos3d import GaussianCounts, Lumos3D, Lumos3DPrediction
from lumos3d_cli.model.pixel_footprint import DEFAULT_FOOTPRINT_SCALE
from lumos3d_cli.pipeline.gaussian_grid import dense_grid_size, densify_grid
from lumos3d_cli.pipeline.model_loading import load_restoration_model
from lumos3d_cli.pipeline.network_pass import NetworkPass, even_subset, run_network
from lumos3d_cli.pipeline.presets import (
    DEFAULT_RESTORE_PRESET,
    RestorePreset,
    get_restore_preset,
)
from lumos3d_cli.pipeline.progress import JobProgress, SilentProgress
from lumos3d_cli.pipeline.quality import QualityMeter, load_references, mean_metrics
from lumos3d_cli.pipeline.sampling_filter import apply_sampling_filter
from lumos3d_cli.pipeline.scene_geometry import (
    Brightened,
    SceneGeometry,
    check_geometry_source,
    place_views,
    register_views,
)
from lumos3d_cli.pipeline.scene_refinement import refine_scene, refinement_targets
from lumos3d_cli.render.gaussian_budget import DEFAULT_MIN_WEIGHT, BudgetReport, fit_budget
from lumos3d_cli.render.hole_filling import OBSERVED_ALPHA, fill_unobserved
from lumos3d_cli.render.render import render

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
    budget: dict | None = None  # the Gaussian budget the scene got (BuiltScene.budget)
    exposure: dict | None = None  # the exposure prior's strength and gain (BuiltScene.exposure)
    uncovered: dict | None = None  # the views' pixels no Gaussian covered and whether they were filled (None: not rendered)
    view_source: str = "render"  # "render": the scene at each camera; "photo restoration": one photo restored in 2D

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
            "restored_views": self.view_source,
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
    """Every camera rendered at its own size, one view at a time (bounded memory at full
    resolution); with `fill` the pixels no Gaussian covers are filled (render.hole_filling)."""
    degree = gaussians.sh_degree if sh_degree is None else min(sh_degree, gaussians.sh_degree)
    images, unobserved = [], []
    for index in range(len(cameras)):
        with torch.no_grad():
            output = render(gaussians, cameras[index], sh_degree=degree)
        image, alpha = output.images[0].cpu(), output.alphas[0].cpu()
        if fill:
            view = fill_unobserved(image, alpha)
            image, fraction = view.image, view.unobserved
        else:
            fraction = float((alpha < OBSERVED_ALPHA).float().mean())
        images.append(image)
        unobserved.append(fraction)
        if progress is not None:
            progress.advance("render views")
    return RenderedViews(images, unobserved, fill)


def _limit_sh(gaussians: Gaussians, sh_degree: int | None) -> Gaussians:
    if sh_degree is None or sh_degree >= gaussians.sh_degree:
        return gaussians
    return Gaussians(gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities,
                     gaussians.sh[:, : (sh_degree + 1) ** 2].contiguous())


@dataclass
class BuiltScene:
    """The scene before rendering: fused Gaussians, the geometry (cameras of every view that has
    one), the views the network saw (indices into the photos), counts, the network image size
    (width, height), seconds per stage, the Gaussian budget it got (`_budget_summary`), the
    refinement's summary (None: not refined) and the exposure prior's gain (`_exposure_summary`);
    for a one-photo scene of a model with a restoration operator, that photo restored in 2D
    [1, 3, H, W] (`photo_restoration`, else None)."""

    gaussians: Gaussians
    geometry: SceneGeometry
    selected: list[int]
    counts: GaussianCounts
    network_size: tuple[int, int]
    timings: dict[str, float]
    budget: dict
    refinement: dict | None = None  # refine.RefinementResult.summary() when the scene was refined
    exposure: dict | None = None  # the exposure prior's strength and gain (None: no restoration operator)
    photo_restoration: torch.Tensor | None = None


def _budget_summary(report: BudgetReport, preset: RestorePreset, grid_size: tuple[int, int]) -> dict:
    """The budget a scene got (summary.json's gaussians.budget): the pixel Gaussians' grid per
    view (width, height), the voxels' footprint multiple, and what `fit_budget` kept."""
    return report.as_dict() | {"max_gaussians": preset.max_gaussians, "min_weight_px": DEFAULT_MIN_WEIGHT,
                               "grid": list(grid_size), "footprint_scale": DEFAULT_FOOTPRINT_SCALE * preset.voxel_scale,
                               "weights_resolution": preset.budget_resolution}


def _exposure_summary(network: NetworkPass, preset: RestorePreset) -> dict | None:
    """summary.json's exposure_prior: its strength and the gain in stops it gave the scene."""
    if network.exposure_stops is None:
        return None
    return {"strength": preset.exposure_prior, "stops": round(network.exposure_stops, 4)}


def with_full_resolution_colours(prediction: Lumos3DPrediction, photos: torch.Tensor, model: Lumos3D) -> Lumos3DPrediction:
    """For a model that predicts a restoration operator: each pixel Gaussian's colour becomes the
    operator applied to the photo [S, 3, H, W] at full resolution, averaged over the Gaussian's
    footprint (the network image only saw a resized copy, which would blur the colours)."""
    if prediction.appearance is None:
        return prediction
    height, width = prediction.depth.shape[-2:]
    with torch.no_grad():
        restored = restore_photos(photos.to(prediction.params.device), prediction.appearance.scene(0))
        colours = footprint_colours(restored, height, width)
        params = with_operator_colours(prediction.params, colours[None], model.architecture.sh_degree)
    return replace(prediction, params=params)


def _timed_network(model: Lumos3D, images: torch.Tensor, selected: list[int], preset: RestorePreset,
                   timings: dict[str, float], progress: JobProgress) -> NetworkPass:
    progress.start("network", 1)
    started = time.perf_counter()
    network = run_network(model, images[selected], preset)
    timings["network"] += time.perf_counter() - started
    progress.advance("network")
    return network


def _restored_photos(network: NetworkPass, photos: torch.Tensor) -> torch.Tensor:
    """All photos [V, 3, H, W] through the scene's predicted operator (its curve and colour matrix;
    the per-view local grids exist only for the views the network saw)."""
    operator = network.prediction.appearance.scene(0)
    global_operator = AppearanceOperator(operator.curve_slopes, operator.matrix, None)
    with torch.no_grad():
        return restore_photos(photos.to(operator.matrix.device), global_operator).cpu()


def _operator_restoration(network: NetworkPass, photos: torch.Tensor, selected: list[int]) -> torch.Tensor:
    """All photos [V, 3, H, W] restored as the Gaussians' colours are: the whole operator (with
    its per-view local grid) for the views the network saw, its curve and matrix for the rest."""
    operator = network.prediction.appearance.scene(0)
    others = sorted(set(range(len(photos))) - set(selected))
    restored = torch.empty(photos.shape, dtype=torch.float32)
    with torch.no_grad():
        restored[selected] = restore_photos(photos[selected].to(operator.matrix.device), operator).cpu()
    if others:
        restored[others] = _restored_photos(network, photos[others])
    return restored


def build_scene(
    images: torch.Tensor, names: list[str], model: Lumos3D, preset: RestorePreset, geometry: str = "auto",
    poses: Path | str | None = None, max_views: int | None = None, mode: str = "low-light",
    progress: JobProgress | None = None, required_views: Sequence[int] = (), fuse_views: Sequence[bool] | None = None,
    sizes: Sequence[tuple[int, int]] | None = None,
) -> BuiltScene:
    """photos [V, 3, H, W] named `names` -> cameras and fused Gaussians. `sizes`: each photo's own
    (width, height) when it was stretched into `images` (`io.images.ImageBatch`; None: the
    tensor's size): the cameras are at those sizes, the network works on the tensor.

    geometry: "network" (the network's cameras and depth), "sfm" (structure-from-motion on the
    brightened photos, the network's depth aligned to its points), "auto" (sfm when it registers
    most views, else network with a warning); `poses` (transforms.json or COLMAP model) gives the
    cameras instead. `max_views` (default: the preset's) caps the views that go through the
    network, which always include `required_views` and the views only the network can place.
    `fuse_views` [V] bool (evaluation's holdout) keeps only those views' Gaussians.

    The preset sets the grid of pixel Gaussians (`pipeline.gaussian_grid`), their voxels (a
    multiple of each point's pixel footprint), the budget (`render.gaussian_budget`: what no
    rendered view shows goes, at most `max_gaussians` stay) and the refinement steps.
    """
    progress = progress or SilentProgress()
    check_geometry_source(geometry)
    timings: dict[str, float] = {"network": 0.0}
    limit = max_views or preset.max_views
    network, selected, brightened = None, [], None
    if model.architecture.appearance == "operator" and geometry != "network":
        # The model restores the photos itself: structure-from-motion sees its restoration, so the
        # network runs first (on an even subset) and again only if SfM leaves views it must place.
        selected = even_subset(len(names), limit, required=list(required_views))
        network = _timed_network(model, images, selected, preset, timings, progress)
        brightened = Brightened(_restored_photos(network, images), "the model's restoration operator")
    registration = register_views(images, names, geometry, poses, mode, progress, brightened, sizes,
                                  preset.sfm_long_side)
    timings.update(registration.seconds)
    unplaced = set(registration.views_needing_network()) - set(selected)
    if network is None or unplaced:
        selected = even_subset(len(names), limit, required=[*required_views, *registration.views_needing_network()])
        network = _timed_network(model, images, selected, preset, timings, progress)
    if len(selected) < len(names):
        logger.info("%d views given; the network sees %d of them, chosen evenly (raise max_views to use more)",
                    len(names), len(selected))
    started = time.perf_counter()
    scene_geometry = place_views(registration, network, selected, names)
    grid_size = dense_grid_size(network.network_size, (images.shape[-1], images.shape[-2]), preset.gaussian_grid)
    prediction, grid_geometry = densify_grid(network.prediction, scene_geometry, grid_size)
    prediction = with_full_resolution_colours(prediction, images[selected], model)
    keep = None if fuse_views is None else torch.tensor([bool(fuse_views[i]) for i in selected])
    if keep is not None and not bool(keep.any()):
        raise InputError("selects none of the network's views", parameter="fuse_views")
    with torch.no_grad():
        # Voxels follow each point's pixel footprint: near detail keeps the grid's resolution
        # while far duplicates still merge (one global size does one or the other; a single
        # photo's huge depth range collapsed into a few hundred voxels with it).
        output = model.assemble(
            prediction, grid_geometry.network_extrinsics[None], grid_geometry.network_intrinsics[None],
            grid_geometry.depth[None], footprint_scale=DEFAULT_FOOTPRINT_SCALE * preset.voxel_scale, fuse_views=keep,
            fuse_pixels=None if grid_geometry.fuse_pixels is None else grid_geometry.fuse_pixels[None],
        )
    network_cameras = Cameras(grid_geometry.network_extrinsics.float(), grid_geometry.network_intrinsics.float(),
                              [grid_size] * len(selected))
    gaussians = apply_sampling_filter(output.gaussians[0].detach().to(device="cpu"), network_cameras)
    timings["fuse"] = time.perf_counter() - started
    started = time.perf_counter()
    # The budget is measured at the cameras the scene is rendered at (held-out ones included:
    # only their poses, never their photos).
    gaussians, budget = fit_budget(gaussians, scene_geometry.cameras, preset.max_gaussians,
                                   resolution=preset.budget_resolution)
    timings["budget"] = time.perf_counter() - started
    gaussians, refinement = _limit_sh(gaussians, preset.sh_degree), None
    restored = None
    if preset.refine_steps > 0:
        started = time.perf_counter()
        if model.architecture.appearance == "operator":
            restored = _operator_restoration(network, images, selected)
        targets, cameras = refinement_targets(network, model, images, restored, selected, names,
                                              scene_geometry.cameras, fuse_views)
        result = refine_scene(gaussians, targets, cameras, preset.refine_steps, progress, preset.refine_side,
                              preset.refine_lr_decay)
        gaussians, refinement = result.gaussians, result.summary()
        timings["refine"] = time.perf_counter() - started
    photo_restoration = None
    if len(names) == 1 and model.architecture.appearance == "operator":
        # One photo: there is nothing to fuse, and the Gaussians' render only approximates the
        # operator applied to the photo's own pixels (what refinement fits them to). On 8 SICE
        # training pairs the render scored 18.80 dB / 0.606 / sharpness 0.55 and the 2D
        # restoration 20.06 / 0.693 / 0.99.
        photo_restoration = restored if restored is not None else _operator_restoration(network, images, selected)
    return BuiltScene(gaussians, scene_geometry, selected, output.counts[0], network.network_size, timings,
                      _budget_summary(budget, preset, grid_size), refinement, _exposure_summary(network, preset),
                      photo_restoration)


def restore_scene(
    batch: ImageBatch, model: Lumos3D, preset: RestorePreset, geometry: str = "auto", poses: Path | str | None = None,
    max_views: int | None = None, mode: str = "low-light", progress: JobProgress | None = None,
) -> RestoredScene:
    """The job on loaded photos and a loaded model (`build_scene`), then every view that has a
    camera rendered at it, at its photo's own size."""
    progress = progress or SilentProgress()
    names = [path.name for path in batch.paths]
    if batch.mixed_sizes:
        odd = [name for name, size in zip(names, batch.original_sizes) if size != batch.size]
        logger.warning("%d of %d photos differ in size from %dx%d (%s): the network sees them stretched to it, their "
                       "cameras and restored views keep each photo's own size and aspect ratio", len(odd), len(names),
                       *batch.size, ", ".join(odd[:5]) + (" ..." if len(odd) > 5 else ""))
    built = build_scene(batch.images, names, model, preset, geometry, poses, max_views, mode, progress,
                        sizes=batch.original_sizes)
    cameras = built.geometry.cameras
    missing = [name for name in names if name not in cameras.names]
    if missing:
        logger.warning("%d view(s) have no camera and are not restored (the network did not see them; raise "
                       "max_views or use structure-from-motion): %s", len(missing), ", ".join(missing))
    progress.start("render views", len(cameras))
    started = time.perf_counter()
    if built.photo_restoration is not None and len(cameras) == 1:
        # A one-photo scene is 2D restoration (BuiltScene.photo_restoration): nothing to render.
        views, uncovered, view_source = [built.photo_restoration[0].clamp(0, 1)], None, "photo restoration"
        progress.advance("render views")
    else:
        rendered = render_views(built.gaussians, cameras, preset.sh_degree, progress, fill=preset.fill_unobserved)
        views, uncovered, view_source = rendered.images, rendered.summary(), "render"
    timings = built.timings | {"render": time.perf_counter() - started}
    inputs = [batch.photo(names.index(name)) for name in cameras.names]
    return RestoredScene(
        built.gaussians, cameras, views, inputs, list(cameras.names), list(batch.paths),
        built.selected, built.counts, built.network_size, built.geometry, preset.name, mode, timings=timings,
        refinement=built.refinement, budget=built.budget, exposure=built.exposure, uncovered=uncovered,
        view_source=view_source,
    )


def check_photo_contents(batch: ImageBatch, patch_size: int) -> None:
    """InputError naming a photo too small to hold one network patch (`patch_size` pixels a side);
    a warning naming the photos that are all black or all saturated (nothing to restore there)."""
    names = [path.name for path in batch.paths]
    for name, (width, height) in zip(names, batch.original_sizes):
        if min(width, height) < patch_size:
            raise InputError(f"{name}: is {width}x{height} pixels, too small for the network (at least {patch_size} "
                             "pixels a side); leave it out")
    black, saturated = frames_without_content(batch.images)
    for kind, indices in (("black", black), ("saturated", saturated)):
        if indices:
            logger.warning("%s %s entirely %s: nothing to restore there (it stays %s)", ", ".join(names[i] for i in indices),
                           "is" if len(indices) == 1 else "are", kind, "black" if kind == "black" else "white")


def restore(
    photos: Path | str | Sequence[Path | str], mode: str = "low-light", checkpoint: Path | str | None = None,
    preset: str = DEFAULT_RESTORE_PRESET, geometry: str = "auto", poses: Path | str | None = None,
    max_views: int | None = None, device: str = "cpu", reference: Path | str | None = None,
    lpips_weights: Path | str | None = None, progress: JobProgress | None = None, refine_steps: int | None = None,
    max_gaussians: int | None = None, gaussian_grid: float | None = None, exposure_prior: float | None = None,
    fill_unobserved: bool | None = None,
) -> RestoredScene:
    """The whole restore job from files: photos (a folder or files: photos, camera RAW, EXR),
    the bundled model of `mode` or `checkpoint`, and optionally reference photos of the same
    views (same file stems) for PSNR/SSIM/LPIPS. `refine_steps` overrides the preset's
    test-time refinement (0: none), `max_gaussians` caps the scene's Gaussians and
    `gaussian_grid` sets the density of pixel Gaussians (`pipeline.gaussian_grid`),
    `exposure_prior` the strength of the exposure prior (`model.appearance.exposure_prior`),
    `fill_unobserved` whether pixels no Gaussian covers are filled (`render.hole_filling`). Write the
    result with `write_restored_scene`."""
    progress = progress or SilentProgress()
    started = time.perf_counter()
    if mode not in MODES:
        raise InputError(f"{mode!r}: use one of {', '.join(MODES)}", parameter="mode")
    if max_views is not None and max_views < 1:
        raise InputError(f"{max_views}: use at least 1", parameter="max_views")
    settings = get_restore_preset(preset, refine_steps, max_gaussians, gaussian_grid, exposure_prior, fill_unobserved)
    check_geometry_source(geometry)
    weights = resolve_checkpoint(checkpoint, mode)
    meter = QualityMeter.create(lpips_weights) if reference is not None else None
    timings: dict[str, float] = {}
    stage_started = time.perf_counter()
    paths = list_images(photos)
    progress.start("load images", len(paths))
    batch = load_images(paths, progress=lambda _: progress.advance("load images"))
    if poses is not None:  # a camera file that does not fit the photos stops the run before the work
        read_given_poses(poses, [path.name for path in paths], batch.original_sizes)
    # References are matched and read before the work, so that a missing one stops the run at once.
    references = None if reference is None else dict(zip(
        (path.name for path in paths), load_references(reference, [path.name for path in paths], batch.original_sizes)))
    timings["load"] = time.perf_counter() - stage_started
    stage_started = time.perf_counter()
    model = load_restoration_model(weights, device)
    timings["load_model"] = time.perf_counter() - stage_started
    check_photo_contents(batch, model.architecture.patch_size)
    scene = restore_scene(batch, model, settings, geometry, poses, max_views, mode, progress)
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
    return scene
