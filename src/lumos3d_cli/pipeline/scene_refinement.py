"""Test-time refinement inside the restore and eval jobs: the fused Gaussians optimised against
the model's own restoration of the photos they were built from (`refine.refine_gaussians`).

The targets are what the forward pass says each view should look like in normal light: for a
model with a restoration operator, the operator applied to the full-resolution photo (every view
with a camera); for a colour-regression model, the network's per-pixel colours of the views it
saw, upsampled to the photos' size (the network image is the whole photo resized: nothing is
cropped). Held-out views (evaluation's holdout protocol) are never fitted.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import torch
import torch.nn.functional as F

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import SH_C0, Gaussians, sh_coefficient_count
from lumos3d_cli.model.gaussian_adapter import SH_START
from lumos3d_cli.model.lumos3d import Lumos3D
from lumos3d_cli.pipeline.network_pass import NetworkPass
from lumos3d_cli.pipeline.progress import JobProgress
from lumos3d_cli.refine.photometric import working_size
from lumos3d_cli.refine.refinement import RefinementResult, refine_gaussians
from lumos3d_cli.refine.settings import DensifySettings, RefineSettings

logger = logging.getLogger(__name__)


def network_colours(network: NetworkPass, model: Lumos3D, size: tuple[int, int]) -> torch.Tensor:
    """The regression network's colours of the views it saw (the DC term of each pixel Gaussian),
    [S, 3, H, W] in [0, 1] at `size` (height, width)."""
    count = sh_coefficient_count(model.architecture.sh_degree)
    params = network.prediction.params[0].detach().float().cpu()  # [S, h, w, C-1], colour-major SH, DC first
    colours = 0.5 + SH_C0 * torch.stack([params[..., SH_START + c * count] for c in range(3)], dim=1)
    return F.interpolate(colours, size=size, mode="bilinear", align_corners=False).clamp(0, 1)


def refinement_targets(
    network: NetworkPass, model: Lumos3D, photos: torch.Tensor, restored_photos: torch.Tensor | None,
    selected: Sequence[int], names: Sequence[str], cameras: Cameras, fitted: Sequence[bool] | None,
    max_side: int | None = None,
) -> tuple[torch.Tensor, Cameras]:
    """(targets [T, 3, h, w], their cameras) for the views that have a camera, a target and are
    fitted. photos [V, 3, H, W] (the working copy); restored_photos [V, 3, H, W] the operator's
    restoration of all photos, or None for a regression model (then only the `selected` views,
    which the network saw, have a target); fitted [V] bool (None: all). With `max_side` each
    target is area-downsampled to the size refinement works at (`refine.photometric.working_size`)
    before they are stacked: at the photos' size they were a third full-resolution copy of every
    photo (1.9 GB for six of 27 MP). The cameras keep the photos' size (refinement rescales them)."""
    if restored_photos is not None:
        sources = {name: restored_photos[index] for index, name in enumerate(names)}
    else:
        colours = network_colours(network, model, tuple(photos.shape[-2:]))
        sources = {names[index]: colours[position] for position, index in enumerate(selected)}
    keep = [i for i, name in enumerate(cameras.names)
            if name in sources and (fitted is None or fitted[list(names).index(name)])]
    height, width = photos.shape[-2:]
    size = (width, height) if max_side is None else working_size(width, height, max_side)

    def at_working_size(image: torch.Tensor) -> torch.Tensor:
        if tuple(image.shape[-2:]) == (size[1], size[0]):
            return image
        return F.interpolate(image[None].float(), size=(size[1], size[0]), mode="area")[0]

    return torch.stack([at_working_size(sources[cameras.names[i]]) for i in keep]), cameras[keep]


def refine_scene(
    gaussians: Gaussians, targets: torch.Tensor, cameras: Cameras, steps: int, progress: JobProgress,
    max_side: int = RefineSettings.max_side, lr_decay_per_100_steps: float = RefineSettings.lr_decay_per_100_steps,
    densify: DensifySettings | None = None, splat_colours: bool = False,
) -> RefinementResult:
    """`steps` of refinement (fewer when the loss stops falling) against `targets` [V, 3, H, W]
    (the `cameras`' views, sRGB in [0, 1]) downsampled to a
    longer side of at most `max_side`, the learning rates falling by `lr_decay_per_100_steps`
    every 100 steps, densified on `densify`'s schedule (None: never), otherwise with the default
    settings, shown as a "refine" progress bar. `splat_colours`: fit the renders as the hole fill
    shows them (RefineSettings.splat_colours; the preset's `fill_unobserved`)."""
    progress.start("refine", steps)
    settings = RefineSettings(steps=steps, max_side=max_side, lr_decay_per_100_steps=lr_decay_per_100_steps,
                              densify=densify, splat_colours=splat_colours)
    result = refine_gaussians(gaussians, cameras, targets, settings,
                              on_step=lambda step, loss: progress.advance("refine"))
    logger.info("refinement: %d steps (%s), loss %.4f -> %.4f, SH degree %d, %d Gaussians -> %d", result.steps_run,
                "stopped early" if result.stopped_early else "all asked", result.loss_curve[0] if result.loss_curve else 0.0,
                result.loss_curve[-1] if result.loss_curve else 0.0, result.sh_degree, len(gaussians), len(result.gaussians))
    return result
