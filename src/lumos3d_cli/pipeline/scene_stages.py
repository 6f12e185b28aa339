"""Building a scene, stage by stage: photos -> (restoration pass) -> registration -> network pass
-> fused scene -> budget -> refinement. Each stage takes the job's state (pipeline/scene_job.py)
and returns it with its product added; `build_scene` runs the chain and times every stage under
its name (summary.json's seconds), so a stage can be timed, skipped or moved on its own. The
Gaussians stay on the model's device from the fusion on.

Structure-from-motion runs on a background thread (COLMAP matches and maps on one core) while the
main one goes on with what needs no cameras, and `registration_result` waits for it; its "sfm"
seconds are the time the job waited, not what it took. On photos brightened by the blind tone
curve (the preset's `sfm_brightening`, or a model without a restoration operator) it needs
nothing from the network and runs beside the network pass and the operator's restoration of the
photos; on the model's restoration it starts after the restoration pass, beside the
restoration of the photos at full resolution.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from functools import partial
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError, NonFiniteError
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.model.appearance.amplified_noise import denoise_photo
from lumos3d_cli.model.appearance.footprint import footprint_colours
from lumos3d_cli.model.appearance.gaussian_colours import with_operator_colours
from lumos3d_cli.model.appearance.operator import AppearanceOperator
from lumos3d_cli.model.appearance.photo_restoration import restore_photos
from lumos3d_cli.model.lumos3d import Lumos3D, Lumos3DPrediction
from lumos3d_cli.model.pixel_footprint import DEFAULT_FOOTPRINT_SCALE
from lumos3d_cli.model.voxelize import PointsBeyondVoxelGrid
from lumos3d_cli.pipeline.gaussian_grid import dense_grid_size, densify_grid
from lumos3d_cli.pipeline.early_registration import EarlyRegistration
from lumos3d_cli.pipeline.module_prefetch import prefetch_modules
from lumos3d_cli.pipeline.network_pass import NetworkPass, even_subset, run_network
from lumos3d_cli.pipeline.presets import RestorePreset
from lumos3d_cli.pipeline.progress import JobProgress, SilentProgress
from lumos3d_cli.pipeline.sampling_filter import apply_sampling_filter
from lumos3d_cli.pipeline.scene_geometry import Brightened, check_geometry_source, place_views, register_views
from lumos3d_cli.pipeline.scene_job import SceneJob
from lumos3d_cli.pipeline.scene_refinement import refine_scene, refinement_targets
from lumos3d_cli.render.clipping_range import require_drawable
from lumos3d_cli.render.gaussian_budget import DEFAULT_MIN_WEIGHT, fit_budget

logger = logging.getLogger(__name__)

Stage = Callable[[SceneJob], SceneJob]


def with_full_resolution_colours(prediction: Lumos3DPrediction, restored: torch.Tensor | None,
                                 model: Lumos3D) -> Lumos3DPrediction:
    """For a model that predicts a restoration operator: each pixel Gaussian's colour becomes the
    operator's restoration of its photo at full resolution, `restored` [S, 3, H, W] (the S views
    the network saw, `operator_restoration`), averaged over the Gaussian's footprint (the network
    image only saw a resized copy, which would blur the colours)."""
    if prediction.appearance is None:
        return prediction
    height, width = prediction.depth.shape[-2:]
    with torch.no_grad():
        colours = footprint_colours(restored.to(prediction.params.device), height, width)
        params = with_operator_colours(prediction.params, colours[None], model.architecture.sh_degree)
    return replace(prediction, params=params)


def _network_pass(job: SceneJob, selected: list[int]) -> NetworkPass:
    job.progress.start("network", 1)
    empty = None if job.empty_views is None else [index for index, view in enumerate(selected) if view in job.empty_views]
    stretch = None
    if job.sizes is not None:  # a photo of another aspect, stretched to the working size (network_pass.run_network)
        height, width = job.photos.shape[-2:]
        stretch = torch.tensor([(job.sizes[view][0] / width) / (job.sizes[view][1] / height) for view in selected],
                               dtype=torch.float64)
    network = run_network(job.model, job.photos[selected], job.preset, job.mode, empty_views=empty, stretch=stretch)
    job.progress.advance("network")
    return network


def _restored_view_by_view(photos: torch.Tensor, views: Sequence[int], operator: AppearanceOperator,
                           restored: torch.Tensor | None = None) -> torch.Tensor:
    """restored[views[i]] = `operator` (its view i's local grid, if any) applied to photos[views[i]],
    one view at a time into `restored` [V, 3, H, W] (made when None), on the CPU. Restoring
    `photos[views]` at once took a full-resolution copy of the photos for the selection and one
    for the result, beside `restored`: 7.8 GB for six photos of 27 MP, where one view's is 0.3."""
    restored = torch.empty(photos.shape, dtype=torch.float32) if restored is None else restored
    with torch.no_grad():
        for position, view in enumerate(views):
            one = operator.views(slice(position, position + 1))
            restored[view] = restore_photos(photos[view:view + 1].to(operator.matrix.device), one)[0].cpu()
    return restored


def _view_operator(network: NetworkPass, selected: Sequence[int], view: int) -> AppearanceOperator:
    """The operator `operator_restoration` restores photo `view` with: the whole operator (its
    local grid for that view) where the network saw it, its curve and matrix elsewhere."""
    operator = network.prediction.appearance.scene(0)
    if view in selected:
        position = list(selected).index(view)
        return operator.views(slice(position, position + 1))
    return AppearanceOperator(operator.curve_slopes, operator.matrix, None)


def operator_restoration(network: NetworkPass, photos: torch.Tensor, selected: Sequence[int]) -> torch.Tensor:
    """All photos [V, 3, H, W] restored as the Gaussians' colours are: the whole operator (with
    its per-view local grid) for the views the network saw, its curve and matrix for the rest
    (every view, with `selected` empty); on the CPU."""
    operator = network.prediction.appearance.scene(0)
    others = sorted(set(range(len(photos))) - set(selected))
    restored = _restored_view_by_view(photos, selected, operator)
    global_operator = AppearanceOperator(operator.curve_slopes, operator.matrix, None)
    return _restored_view_by_view(photos, others, global_operator, restored)


# -- the stages ----------------------------------------------------------------------------------


def restoration_pass(job: SceneJob) -> SceneJob:
    """A model that restores the photos itself runs first, on an even subset of the views, so
    that structure-from-motion sees its restoration (SIFT finds more features on it than on the
    blind tone curve of the dark photos); other models, presets whose structure-from-motion sees
    the tone curve, and network geometry skip this."""
    if not job.has_operator or job.geometry_source == "network" or job.preset.sfm_brightening != "restoration":
        return job
    job.selected = even_subset(len(job.names), job.view_limit, required=list(job.required_views))
    job.network = _network_pass(job, job.selected)
    job.brightened = Brightened(operator_restoration(job.network, job.photos, []), "the model's restoration operator")
    return job


def _in_background(call: Callable[[], object]) -> Future:
    """`call` started on a thread of its own; its Future gives the result or raises its error."""
    executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="lumos3d-sfm")
    future = executor.submit(call)
    executor.shutdown(wait=False)  # the thread ends with the call
    return future


def registration(job: SceneJob) -> SceneJob:
    """The cameras known before (the rest of) the network pass: given poses, structure-from-motion
    or none (`pipeline.scene_geometry.register_views`). Structure-from-motion leaves a core idle:
    the modules later stages import load meanwhile (`pipeline.module_prefetch`), and it runs on
    its own thread (module docstring)."""
    early = job.early_registration
    register = partial(register_views, job.photos, job.names, job.geometry_source, job.poses, job.progress,
                       job.brightened, job.sizes, job.preset.sfm_long_side,
                       None if early is None else early.colmap_run)
    if job.geometry_source == "network" or len(job.names) < 2:  # no structure-from-motion: nothing to wait for
        job.registration = register()
        return job
    prefetch_modules()
    job.pending_registration = _in_background(register)
    return job


def registration_result(job: SceneJob) -> SceneJob:
    """Waits for the structure-from-motion that runs beside the network pass (its errors are
    raised here)."""
    if job.pending_registration is not None:
        pending, job.pending_registration = job.pending_registration, None
        job.registration = pending.result()
    return job


def network_pass(job: SceneJob) -> SceneJob:
    """The forward pass over the views the network sees: an even subset up to the view limit,
    always holding the required views and those only the network can place (the restoration
    pass is reused when it already covers them). While structure-from-motion is still running,
    those are not known yet: the pass runs on the subset, and again after it if it must."""
    needed = [] if job.registration is None else job.registration.views_needing_network()
    if job.network is not None and not set(needed) - set(job.selected):
        return job
    job.selected = even_subset(len(job.names), job.view_limit, required=[*job.required_views, *needed])
    job.network = _network_pass(job, job.selected)
    job.restored_photos = None  # of the views an earlier pass saw
    if len(job.selected) < len(job.names):
        logger.info("%d views given; the network sees %d of them, chosen evenly (raise max_views to use more)",
                    len(job.names), len(job.selected))
    return job


def photo_restoration_of_views(job: SceneJob) -> SceneJob:
    """The operator's restoration of every photo (`operator_restoration`), once per network pass:
    the Gaussians' colours (`fusion`) and refinement's targets. It needs only the network pass,
    so it runs while structure-from-motion may still be running."""
    if job.has_operator and job.restored_photos is None:
        job.restored_photos = operator_restoration(job.network, job.photos, job.selected)
    return job


def fusion(job: SceneJob) -> SceneJob:
    """Every view placed in one frame (`place_views`; the preset's depth sweep compares the
    operator's restoration of the photos, or the photos themselves for a model without one), the
    pixel Gaussians on the preset's grid with the operator's colours from the full-resolution
    photos, fused into voxels that follow
    each point's pixel footprint, and the network grid baked into their size (sampling filter).
    The Gaussians stay on the model's device."""
    preset = job.preset
    unplaced = _views_only_the_network_placed(job)
    if unplaced:  # shown restored in 2D (`photo_restoration`), and kept out of the scene
        job.fuse_views = [(job.fuse_views is None or bool(job.fuse_views[view])) and view not in unplaced
                          for view in range(len(job.names))]
    restored = None if job.restored_photos is None else job.restored_photos[job.selected]
    fused = None if job.fuse_views is None else [job.fuse_views[i] for i in job.selected]
    job.geometry = place_views(job.registration, job.network, job.selected, job.names,
                               restored if restored is not None else job.photos[job.selected], preset.depth_sweep, fused)
    if unplaced:  # (place_views has named them)
        logger.warning("those %d view(s) are shown as their photos restored in 2D and kept out of the scene",
                       len(unplaced))
    job.grid_size = dense_grid_size(job.network.network_size, (job.photos.shape[-1], job.photos.shape[-2]),
                                    preset.gaussian_grid)
    prediction, grid_geometry = densify_grid(job.network.prediction, job.geometry, job.grid_size)
    prediction = with_full_resolution_colours(prediction, restored, job.model)
    keep = None if job.fuse_views is None else torch.tensor([bool(job.fuse_views[i]) for i in job.selected])
    if keep is not None and not bool(keep.any()):
        raise InputError("selects none of the network's views", parameter="fuse_views")
    with torch.no_grad():
        # Voxels follow each point's pixel footprint: near detail keeps the grid's resolution
        # while far duplicates still merge (one global size does one or the other; a single
        # photo's huge depth range collapsed into a few hundred voxels with it).
        try:
            output = job.model.assemble(
                prediction, grid_geometry.network_extrinsics[None], grid_geometry.network_intrinsics[None],
                grid_geometry.depth[None], footprint_scale=DEFAULT_FOOTPRINT_SCALE * preset.voxel_scale, fuse_views=keep,
                fuse_pixels=None if grid_geometry.fuse_pixels is None else grid_geometry.fuse_pixels[None],
            )
        except PointsBeyondVoxelGrid as error:  # finite, but no voxel index reaches them
            raise _unbuildable_scene(job, str(error)) from None
    grid_cameras = Cameras(grid_geometry.network_extrinsics.float(), grid_geometry.network_intrinsics.float(),
                           [job.grid_size] * len(job.selected))
    job.gaussians = apply_sampling_filter(output.gaussians[0].detach(), grid_cameras)
    _require_finite_scene(job)
    job.counts = output.counts[0]
    return job


def _require_finite_scene(job: SceneJob) -> None:
    """InputError naming what most likely made the fused Gaussians non-finite (`_unbuildable_scene`)."""
    try:
        job.gaussians.require_finite("the fused scene's Gaussians")
    except NonFiniteError as error:
        raise _unbuildable_scene(job, str(error)) from None


def _unbuildable_scene(job: SceneJob, what: str) -> InputError:
    """The error for a fused scene that cannot be built (`what` went wrong), naming its most likely
    cause: the camera file (a position in extreme units puts points beyond the voxel grid or
    overflows the footprints), else the weights (the network's output itself was checked, but a
    head that gives extreme depths or scales overflows them)."""
    if job.poses is not None:
        return InputError(f"{job.poses}: {what}; check the camera file's positions and units (if they are right, the "
                          "checkpoint's weights)", parameter="poses")
    source = job.model.provenance.get("path", "the model's weights")
    return InputError(f"{source}: {what}, on these photos: damaged or diverged weights; use another checkpoint")


def budget(job: SceneJob) -> SceneJob:
    """What no view shows goes, at most the preset's `max_gaussians` stay, measured at the cameras
    the scene is rendered at (held-out ones included: only their poses, never their photos); the
    SH bands above the preset's degree go."""
    preset = job.preset
    grid_pixels = 0 if job.grid_size is None else job.grid_size[0] * job.grid_size[1]
    gaussians, report = fit_budget(job.gaussians, job.geometry.cameras, preset.max_gaussians,
                                   resolution=preset.budget_resolution, grid_pixels=grid_pixels)
    if report.kept == 0 and report.dropped_unseen > 0:  # every view would be black
        where, parameter = (None, None) if job.poses is None else (str(job.poses), "poses")
        require_drawable(job.gaussians.means, job.geometry.cameras, where, parameter=parameter)  # extreme units
        # in range, yet outside every view: cameras that look elsewhere, or focal lengths in another unit
        advice = ("check the cameras' focal lengths (pixels of the photos) and directions" if where else
                  "the cameras placed for these photos miss the scene: try the other geometry source")
        raise InputError(f"{where + ': ' if where else ''}no Gaussian of the scene falls inside any camera's view; {advice}",
                         parameter=parameter)
    job.gaussians = gaussians if preset.sh_degree is None else gaussians.with_sh_degree(preset.sh_degree)
    job.budget = report.as_dict() | {
        "max_gaussians": preset.max_gaussians, "min_weight_px": DEFAULT_MIN_WEIGHT, "grid": list(job.grid_size),
        "footprint_scale": DEFAULT_FOOTPRINT_SCALE * preset.voxel_scale, "weights_resolution": preset.budget_resolution,
    }
    return job


def refinement(job: SceneJob) -> SceneJob:
    """The preset's steps of test-time refinement against the model's own restoration of the
    fitted views (`pipeline.scene_refinement`), at least one per fitted view where the preset asks
    (`RestorePreset.refinement_steps`: one view a step, so each is fitted once), densified on the preset's
    schedule within its Gaussian cap; skipped at 0 steps."""
    if job.preset.refine_steps <= 0:
        return job
    if len(_views_restored_in_2d(job)) == len(job.names):
        # the views are the photos restored in 2D (`photo_restoration`), which no refinement
        # changes: a one-photo restore's steps were 3.6 s of its 3.8 s
        return job
    targets, cameras = refinement_targets(job.network, job.model, job.photos, job.restored_photos, job.selected,
                                          job.names, job.geometry.cameras, job.fuse_views, job.preset.refine_side)
    densify = job.preset.densify
    if densify is not None:  # the preset's cap holds for the Gaussians densification adds
        densify = replace(densify, max_gaussians=job.preset.max_gaussians)
    # The views are shown filled (render.hole_filling) unless the preset leaves them black: refinement
    # fits what will be shown. Fitting the render over black and showing it filled brightened
    # every partly covered pixel: shrub's refined foliage renders at alpha 0.89 on average.
    result = refine_scene(job.gaussians, targets, cameras, job.preset.refinement_steps(len(cameras)), job.progress,
                          job.preset.refine_side, job.preset.refine_lr_decay, densify,
                          splat_colours=job.preset.fill_unobserved)
    job.gaussians, job.refinement = result.gaussians, result.summary()
    return job


def _views_only_the_network_placed(job: SceneJob) -> list[int]:
    """The views structure-from-motion did not register in a scene it placed, for a model with a
    restoration operator: the network's cameras, carried into structure-from-motion's frame, are
    all that places them, and the bundled models' nearly collapse onto one pose (on castle-P19,
    whose 12 photos SfM registers 8 of, the other 4 were placed 156-179 degrees off, each view a
    ghosted overlay and their Gaussians laid over the registered views)."""
    registration = job.registration
    if job.photo_at_own_size is None or not job.has_operator or registration is None or registration.source != "sfm":
        return []  # (evaluation renders every view it scores: its scenes keep these views)
    return [view for view in range(len(job.names)) if not bool(registration.known[view])]


def _views_restored_in_2d(job: SceneJob) -> list[int]:
    """The views shown as their photos restored in 2D (`photo_restoration`) rather than as renders
    of the scene, for a model with a restoration operator: every view of one photo, or of photos
    structure-from-motion could not place (`auto` fell back to the network's cameras); else the
    views only the network placed (`_views_only_the_network_placed`)."""
    if not job.has_operator:
        return []
    unplaced = job.photo_at_own_size is not None and job.registration is not None and job.registration.fell_back_to_network
    if len(job.names) == 1 or unplaced:
        return list(range(len(job.names)))
    return _views_only_the_network_placed(job)


def photo_restoration(job: SceneJob) -> SceneJob:
    """One photo has nothing to fuse, and the Gaussians' render only approximates the operator
    applied to the photo's own pixels (what refinement fits them to): a one-photo scene of an
    operator model keeps that 2D restoration as its view. On 8 SICE training pairs the render
    scored 18.80 dB / 0.606 / sharpness 0.55 and the 2D restoration 20.06 / 0.693 / 0.99.
    Photos that structure-from-motion could not place are kept the same way: the network's
    cameras (the bundled models put every view at nearly one pose) make each render a ghosted
    overlay of all the views, where the 2D restoration is that photo's own (on 8 of 33 real
    scenes in a QA sweep, every view was such an overlay).
    So are the views only the network's cameras place in a scene structure-from-motion placed
    (`_views_only_the_network_placed`).
    Nor has a photo restored in 2D other views to average the noise its restoration amplified:
    with the preset's `denoise_photo` that noise is measured and removed
    (`model.appearance.amplified_noise`)."""
    empty = set(job.empty_views or ())  # shown as the photo itself (a black or white frame)
    in_2d = [view for view in _views_restored_in_2d(job) if view in job.selected and view not in empty]
    if not in_2d:
        return job
    if len(job.names) > 1:
        logger.warning("%d view(s) are their photos restored in 2D, one at a time: no geometry places them",
                       len(in_2d))
    height, width = job.photos.shape[-2:]
    restored: dict[int, torch.Tensor] = {}
    for view in in_2d:
        restored[view] = job.restored_photos[view]
        if job.photo_at_own_size is not None and job.sizes is not None and tuple(job.sizes[view]) != (width, height):
            # stretched into the working tensor with the others: restored at its own size instead
            with torch.no_grad():
                operator = _view_operator(job.network, job.selected, view)
                photo = job.photo_at_own_size(view)[None].to(operator.matrix.device)
                restored[view] = restore_photos(photo, operator)[0].cpu()
    if job.preset.denoise_photo:
        results = {view: denoise_photo(image) for view, image in restored.items()}
        restored = {view: result.image for view, result in results.items()}
        job.denoising = results[in_2d[0]].summary() if len(job.names) == 1 else {
            "views": [job.names[view] for view in in_2d],
            "noise_level": [round(results[view].noise_level, 5) for view in in_2d],
            "filtered": [results[view].filtered for view in in_2d], "strength": results[in_2d[0]].summary()["strength"]}
    job.photo_restoration, job.views_in_2d = restored, in_2d
    return job


# The chain, in order: (timing key, stage). "network" appears twice: both passes count there.
SCENE_STAGES: tuple[tuple[str, Stage], ...] = (
    ("network", restoration_pass),
    ("sfm", registration),
    ("network", network_pass),
    ("fuse", photo_restoration_of_views),
    ("sfm", registration_result),
    ("network", network_pass),  # the views structure-from-motion could not place, if any
    ("fuse", photo_restoration_of_views),  # again only if that pass ran
    ("fuse", fusion),
    ("budget", budget),
    ("refine", refinement),
    ("refine", photo_restoration),
)


def build_scene(
    images: torch.Tensor, names: list[str], model: Lumos3D, preset: RestorePreset, geometry: str = "auto",
    poses: Path | str | None = None, max_views: int | None = None, mode: str = "low-light",
    progress: JobProgress | None = None, required_views: Sequence[int] = (), fuse_views: Sequence[bool] | None = None,
    sizes: Sequence[tuple[int, int]] | None = None, early_registration: EarlyRegistration | None = None,
    empty_views: Sequence[int] | None = None, photo_at_own_size: Callable[[int], torch.Tensor] | None = None,
) -> SceneJob:
    """photos [V, 3, H, W] named `names` -> cameras and fused Gaussians, through SCENE_STAGES.
    `sizes`: each photo's own (width, height) when it was stretched into `images`
    (`io.images.ImageBatch`; None: the tensor's size): the cameras are at those sizes, the network
    works on the tensor.

    geometry: "network" (the network's cameras and depth), "sfm" (structure-from-motion on the
    brightened photos, the network's depth aligned to its points), "auto" (sfm when it registers
    most views, else network with a warning); `poses` (transforms.json or COLMAP model) gives the
    cameras instead. `max_views` (default: the preset's) caps the views that go through the
    network, which always include `required_views` and the views only the network can place.
    `fuse_views` [V] bool (evaluation's holdout) keeps only those views' Gaussians.
    `early_registration`: structure-from-motion on these photos' blind tone curve, started before
    the job (`pipeline.early_registration`), for the preset's size. `empty_views`: the photos found
    all black or saturated at their own size (the exposure prior meters without them; None: they
    are judged on `images`). `photo_at_own_size` (index -> [3, h, w]; a restore's): the views no
    geometry places are then shown as their photos restored in 2D at their own size and kept out
    of the scene (`photo_restoration`); without it (evaluation) every view but a one-photo
    scene's is a render.

    The preset sets the grid of pixel Gaussians (`pipeline.gaussian_grid`), their voxels (a
    multiple of each point's pixel footprint), the budget (`render.gaussian_budget`: what no
    rendered view shows goes, at most `max_gaussians` stay) and the refinement steps.
    """
    check_geometry_source(geometry)
    if early_registration is not None and ([path.name for path in early_registration.paths] != list(names)
                                           or early_registration.long_side != preset.sfm_long_side):
        raise ValueError("the early registration was started for other photos or another size")
    job = SceneJob(images, list(names), model, preset, geometry, poses, max_views, mode,
                   progress if progress is not None else SilentProgress(), required_views, fuse_views, sizes,
                   early_registration, empty_views, photo_at_own_size)
    for name, stage in SCENE_STAGES:
        started = time.perf_counter()
        job = stage(job)
        job.timings[name] = job.timings.get(name, 0.0) + time.perf_counter() - started
    return job


