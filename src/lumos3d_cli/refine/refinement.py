"""Test-time refinement: starting from the forward pass, Adam on the Gaussians (and optionally the
cameras) against the restored input views, through the CPU rasterizer's backward."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field

import torch

from lumos3d_cli.checks import require_finite, require_unit_range
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.refine.adam import FUSED_DEVICES, FusedAdam
from lumos3d_cli.refine.camera_corrections import CameraCorrections
from lumos3d_cli.refine.densification import DensificationStep, GradientStatistics, densify
from lumos3d_cli.refine.early_stop import EarlyStop
from lumos3d_cli.refine.parameters import GaussianParameters, scene_extent
from lumos3d_cli.refine.photometric import photometric_loss, working_views
from lumos3d_cli.refine.settings import RefineSettings
from lumos3d_cli.refine.sh_degree import choose_sh_degree
from lumos3d_cli.render.hole_filling import splat_colours
from lumos3d_cli.render.render import render

logger = logging.getLogger(__name__)

StepCallback = Callable[[int, float], None]


@dataclass
class RefinementResult:
    """gaussians: the refined scene (detached, SH truncated to `sh_degree`); cameras: the input
    cameras with corrected extrinsics (as given unless cameras were refined, and for views
    without a usable camera); loss_curve: the photometric loss of each step's views at the
    working resolution; steps_run <= the steps asked for; stopped_early: the loss stopped falling
    (settings.patience, settings.tolerance); sh_degree: the degree kept; working_size: (width,
    height) of the images fitted; seconds: wall time; lr_decay_per_100_steps: the factor the
    learning rates fell by every 100 steps (settings.lr_decay_per_100_steps); densification:
    (step, what it did) for each densification (settings.densify); splat_colours: the renders were
    fitted divided by their alpha (settings.splat_colours), else over black."""

    gaussians: Gaussians
    cameras: Cameras
    loss_curve: list[float]
    steps_run: int
    stopped_early: bool
    sh_degree: int
    working_size: tuple[int, int]
    seconds: float
    lr_decay_per_100_steps: float = 1.0
    densification: list[tuple[int, DensificationStep]] = field(default_factory=list)
    splat_colours: bool = False

    def summary(self) -> dict:
        """The refinement's entry of summary.json."""
        return {
            "steps": self.steps_run, "stopped_early": self.stopped_early, "sh_degree": self.sh_degree,
            "working_size": list(self.working_size), "lr_decay_per_100_steps": self.lr_decay_per_100_steps,
            "fitted": "splat colours" if self.splat_colours else "over black",
            "seconds": round(self.seconds, 3), "loss_curve": [round(value, 6) for value in self.loss_curve],
            "densification": [{"step": step} | asdict(done) for step, done in self.densification],
        }


def _usable_views(cameras: Cameras) -> list[int]:
    """Views whose camera is finite (a failed registration can leave NaN extrinsics)."""
    finite = torch.isfinite(cameras.extrinsics).flatten(1).all(1) & torch.isfinite(cameras.intrinsics).flatten(1).all(1)
    usable = [int(v) for v in torch.nonzero(finite).flatten()]
    if len(usable) < len(cameras):
        skipped = [cameras.names[v] or str(v) for v in range(len(cameras)) if v not in usable]
        logger.warning("refinement skips %d view(s) without a usable camera: %s", len(skipped), ", ".join(skipped))
    if not usable:
        raise ValueError("refinement needs at least one view with a finite camera")
    return usable


def _view_batches(views: int, per_step: int, generator: torch.Generator) -> Iterator[list[int]]:
    """Endless batches of up to `per_step` distinct views: each epoch is a shuffle of all views cut
    into batches (its last may be shorter), so every view comes up once per epoch."""
    while True:
        order = torch.randperm(views, generator=generator).tolist()
        for start in range(0, views, per_step):
            yield order[start : start + per_step]


def _optimizer(parameters: GaussianParameters, corrections: CameraCorrections | None, settings: RefineSettings,
               extent: float) -> FusedAdam | torch.optim.Adam:
    groups = [
        (parameters.offsets, settings.position_lr * extent), (parameters.quats, settings.rotation_lr),
        (parameters.log_scales, settings.scale_lr), (parameters.opacity_logits, settings.opacity_lr),
        (parameters.colour, settings.colour_lr), (parameters.sh_rest, settings.sh_rest_lr),
    ]
    if corrections is not None:
        groups += [(corrections.rotations, settings.camera_rotation_lr),
                   (corrections.translations, settings.camera_translation_lr * extent)]
    groups = [(tensor, lr) for tensor, lr in groups if tensor.requires_grad and tensor.numel()]
    # eps 1e-15 as 3DGS: a Gaussian's gradients can be 1e-9 and below, and Adam's default 1e-8
    # would shrink its steps far under the learning rate. The fused kernel (CPU and CUDA) does the
    # same update in one pass: 21 -> 6 ms a step for 382k Gaussians on 2 cores; called without
    # torch.optim's step, which imports torch._dynamo (refine/adam.py).
    if parameters.offsets.device.type in FUSED_DEVICES:
        return FusedAdam(groups, eps=1e-15)
    return torch.optim.Adam([{"params": [tensor], "lr": lr} for tensor, lr in groups], eps=1e-15)


def _decay_learning_rates(optimizer: FusedAdam | torch.optim.Adam, first_rates: list[float], factor: float) -> None:
    """Each group's rate becomes its first rate times `factor` (closed form: step k's rate depends
    on k alone, not on the steps asked for)."""
    for group, first in zip(optimizer.param_groups, first_rates):
        group["lr"] = first * factor


# A caller's torch.no_grad() or inference_mode() (around a whole restore, as around a model call)
# must not turn the fit's backward pass off
@torch.inference_mode(False)
@torch.enable_grad()
def refine_gaussians(
    gaussians: Gaussians, cameras: Cameras, targets: torch.Tensor, settings: RefineSettings | None = None,
    on_step: StepCallback | None = None,
) -> RefinementResult:
    """Fit `gaussians` to `targets` [V, 3, H, W] (sRGB in [0, 1], the restored input views) seen
    by `cameras` [V] (any sizes: they describe the targets' images and are rescaled to them).
    With `settings.splat_colours` each render is divided by its alpha before it is compared (what
    the hole fill shows of it), otherwise it is the render over black.

    Only the given views are fitted (a held-out view must not be among them). Every step renders
    `settings.views_per_step` views at the working resolution (the longer side at most
    `settings.max_side`), takes (1 - w) L1 + w (1 - SSIM) and one Adam step; it stops after
    `settings.steps` or when the loss stops falling. `on_step(step, loss)` is called after each
    step (step counts from 1). With `settings.densify` the Gaussians are split, cloned and pruned
    every few steps (`refine.densification`), so the result may hold more or fewer of them.
    Views whose camera is not finite are skipped with a warning.
    Runs on the Gaussians' device (the render backend follows it: gsplat on CUDA); the targets
    move there.
    """
    settings = settings or RefineSettings()
    started = time.perf_counter()
    if targets.dim() != 4 or targets.shape[1] != 3 or targets.shape[0] != len(cameras):
        raise ValueError(f"targets {tuple(targets.shape)} must be [V, 3, H, W] for the {len(cameras)} cameras")
    gaussians = gaussians.detach()
    gaussians.require_finite("refinement input")
    require_finite("refinement targets", targets)
    if targets.numel():  # 0..255 targets were fitted as they were, silently
        require_unit_range("refinement targets", targets)
    usable = _usable_views(cameras)
    images, working = working_views(targets[usable].to(gaussians.means.device), cameras[usable].to(device="cpu"),
                                    settings.max_side)
    centres = working.centers()
    extent = scene_extent(gaussians.means.detach(), centres)
    degree = gaussians.sh_degree
    if settings.choose_sh_degree:
        degree = choose_sh_degree(gaussians, working, images, settings.ssim_weight, settings.sh_tolerance)
    gaussians = gaussians.with_sh_degree(degree)
    parameters = GaussianParameters(gaussians, settings.positions, centres, extent)
    pinned = torch.arange(len(working)) == 0  # the first view holds the world frame
    corrections = (CameraCorrections(working.extrinsics.to(gaussians.means.device), pinned.to(gaussians.means.device))
                   if settings.refine_cameras else None)
    optimizer = _optimizer(parameters, corrections, settings, extent)
    stop = EarlyStop(len(working), settings.patience, settings.tolerance)
    batches = _view_batches(len(working), min(settings.views_per_step, len(working)),
                            torch.Generator().manual_seed(settings.seed))
    single_views = [working[[v]] for v in range(len(working))]
    density = settings.densify
    statistics = GradientStatistics(len(gaussians), gaussians.means.device) if density is not None else None
    split_generator = torch.Generator().manual_seed(settings.seed)
    curve: list[float] = []
    densifications: list[tuple[int, DensificationStep]] = []
    first_rates = [group["lr"] for group in optimizer.param_groups]
    for step in range(settings.steps):
        batch = next(batches)
        current = parameters.gaussians()
        losses = []
        for view in batch:
            if corrections is None:
                output = render(current, single_views[view], sh_degree=degree)
            else:
                output = render(corrections.moved_gaussians(view, current, degree), single_views[view])
            fitted = splat_colours(output.images, output.alphas) if settings.splat_colours else output.images
            losses.append(photometric_loss(fitted, images[view : view + 1], settings.ssim_weight))
        loss = torch.stack(losses).mean()
        require_finite(f"refinement loss at step {step + 1}", loss.detach())
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if statistics is not None and parameters.offsets.grad is not None:
            # densification renders one view a step (RefineSettings): the gradient is that view's
            statistics.add(parameters.offsets.grad, current.means, output.radii[0], single_views[batch[0]])
        optimizer.step()
        _decay_learning_rates(optimizer, first_rates, settings.lr_decay_per_100_steps ** ((step + 1) / 100))
        parameters.normalise()
        if density is not None and density.due(step + 1, settings.steps):
            densified = densify(parameters, optimizer, statistics, density, split_generator)
            statistics = GradientStatistics(densified.gaussians, gaussians.means.device)
            densifications.append((step + 1, densified))
            stop.restart()  # new Gaussians get `patience` steps to settle (stopping at once left them unfitted)
        curve.append(loss.item())
        if on_step is not None:
            on_step(step + 1, curve[-1])
        stop.update({view: value.item() for view, value in zip(batch, losses)})
        if stop.should_stop:
            logger.info("refinement stopped at step %d: the loss fell less than %.2g%% in %d steps",
                        step + 1, 100 * settings.tolerance, settings.patience)
            break
    refined = parameters.gaussians().detach()
    refined.require_finite("refined Gaussians")
    if curve:
        logger.info("refined %d Gaussians in %d steps (%.1f s): loss %.5f -> %.5f (the first and last %d steps)",
                    len(refined), len(curve), time.perf_counter() - started, _mean(curve[:len(working)]),
                    _mean(curve[-len(working):]), min(len(curve), len(working)))
    extrinsics = cameras.extrinsics.clone()
    if corrections is not None:
        extrinsics[usable] = corrections.corrected_extrinsics().to(extrinsics)
    return RefinementResult(
        refined, Cameras(extrinsics, cameras.intrinsics.clone(), list(cameras.sizes), list(cameras.names)),
        curve, len(curve), stop.should_stop, degree, (images.shape[-1], images.shape[-2]), time.perf_counter() - started,
        settings.lr_decay_per_100_steps, densifications, settings.splat_colours,
    )


def _mean(values: list[float]) -> float:
    return sum(values) / len(values)


