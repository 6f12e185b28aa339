"""What a refinement run may change, how fast, at which resolution and when it stops."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


Positions = Literal["free", "ray", "fixed"]


@dataclass(frozen=True)
class DensifySettings:
    """every: steps between densifications (the first after `every` steps); until: no
    densification after this step; fraction: the share of the Gaussians densified each time (the
    largest mean image-space gradients among those drawn since the last densification);
    prune_opacity: Gaussians below this opacity go (3DGS's 0.005); max_gaussians: the most
    Gaussians the scene may reach (None: no cap). Defaults chosen on the development scenes
    (pipeline.presets.DENSIFY says how)."""

    every: int = 10
    until: int = 80
    fraction: float = 0.05
    prune_opacity: float = 0.005
    max_gaussians: int | None = None

    def __post_init__(self) -> None:
        if self.every < 1 or self.until < 0:
            raise ValueError(f"every={self.every} must be >= 1 and until={self.until} >= 0")
        if not 0 <= self.fraction <= 1:
            raise ValueError(f"fraction={self.fraction} must be in [0, 1]")
        if not 0 <= self.prune_opacity < 1:
            raise ValueError(f"prune_opacity={self.prune_opacity} must be in [0, 1)")
        if self.max_gaussians is not None and self.max_gaussians < 1:
            raise ValueError(f"max_gaussians={self.max_gaussians} must be >= 1")

    def due(self, step: int, steps: int) -> bool:
        """Whether to densify after step `step` (counted from 1) of a run of `steps`: never in
        the last `every` steps, which would leave new Gaussians that were never fitted."""
        return step % self.every == 0 and step <= min(self.until, steps - self.every)


@dataclass(frozen=True)
class RefineSettings:
    """steps: the most optimiser steps (one step = `views_per_step` views rendered, compared and
    back-propagated); max_side: the longer side, in pixels, of the images optimised against (the
    targets are area-downsampled to it, never enlarged); positions: "free" (3D), "ray" (along the
    ray from the nearest camera through the Gaussian) or "fixed"; refine_cameras: also correct
    every camera but the first (which holds the world frame); learning rates are per Adam step in
    the units of each parameter (log scale, opacity logit, SH coefficient, radians) or, for
    positions and camera translations, relative to the scene's extent; early stop: when the
    running loss over all views has not fallen by `tolerance` (relative) for `patience` steps;
    ssim_weight: loss = (1 - w) L1 + w (1 - SSIM); splat_colours: fit each view's render divided
    by its alpha (render.hole_filling.splat_colours), which is what a filled view shows, instead of
    the render over black; choose_sh_degree: drop the SH bands that do
    not lower the loss (`sh_degree.choose_sh_degree`); seed: the view order;
    lr_decay_per_100_steps: every learning rate decays exponentially, by this factor every 100
    steps (1: constant rates, as 3DGS's but for positions, which it decays by 0.01 over its 30,000
    steps); the schedule does not depend on `steps`, so a shorter run is the start of a longer one.

    Defaults measured on buu's demo (benchmarks/refinement.py; 7 fitted views, 1 held out,
    60 steps): 3DGS's learning rates for positions and rotations, twice its opacity and scale
    rates, four times its colour rate with the view-dependent bands at a twentieth of it, as in
    3DGS (+0.36 dB on the held-out view over 3DGS's rates; twice these gained no more); free
    positions (along rays or fixed: within 0.1 dB); one view per step (two views per step for
    half the steps: -0.3 dB); max side 256 (the demo's full 250 px; 128 px: -0.5 dB); cameras not
    refined (refining buu's structure-from-motion cameras cost 0.09 dB at these camera rates,
    0.06 dB at 1e-4 for both); early stop after 20 steps under 1 % (of 400 steps asked it ran 178,
    with the held-out PSNR of all 400 within 0.02 dB). The colour rate was then doubled to eight
    times 3DGS's (the bands' rate kept) on the development scenes (buu and shrub, both modes,
    holdout, the mean of four; PSNR / SSIM / sharpness): `balanced` 20.92 / 0.674 / 0.81 at 1e-2,
    20.92 / 0.684 / 0.845 at 2e-2, 20.90 / 0.687 / 0.86 at 2.5e-2, 20.88 / 0.690 / 0.88 at 3e-2,
    20.77 / 0.694 / 0.92 at 5e-2: each view's Gaussians settle on its detail in the one or two
    steps that fit it, but a faster rate also fits the noise the operator amplifies in buu's
    darkest photos (its low-light row 24.90, 24.81, 24.74, 24.66 dB), so 2e-2, where the mean's
    PSNR holds; `fast` 20.52 / 0.606 / 0.65 -> 20.52 / 0.612 / 0.70 there. The SSIM weight is
    then 0.3 rather than 3DGS's 0.2, chosen there too (`balanced`): 20.92 / 0.684 / 0.847 at 0.2,
    20.91 / 0.685 / 0.858 at 0.3, 20.89 / 0.685 / 0.865 at 0.4 (buu's low light +0.04 dB at 0.3,
    shrub's rows -0.04 to -0.05); `fast` 20.53 / 0.612 / 0.70 -> 20.53 / 0.613 / 0.71. SSIM's
    window asks for the edges L1 averages away, and 0.3 is where the views reach sharpness 0.85
    with the mean's PSNR within 0.02 dB (a faster colour rate trades the same way: 2.5e-2 scored
    20.90 / 0.687 / 0.86). Adam's first step moves every colour by its rate whatever the residual,
    so a view fitted once takes one such step; a colour fitted by least squares to every view
    instead (the residuals accumulated over the views through the rendered weights) scored, after
    refinement, 20.47 / 0.679 / 0.81 (one pass) and 20.19 / 0.676 / 0.79 (three: the views'
    copies of a point disagree on where it is, and their mean blurs it), before it 20.18 / 0.695 /
    0.85, and regularised towards the current colour 20.92 / 0.684 / 0.839: nothing to gain."""

    steps: int = 100
    max_side: int = 256
    views_per_step: int = 1
    positions: Positions = "free"
    refine_cameras: bool = False
    position_lr: float = 1.6e-4
    scale_lr: float = 1e-2
    opacity_lr: float = 1e-1
    rotation_lr: float = 1e-3
    colour_lr: float = 2e-2
    sh_rest_lr: float = 1e-2 / 20  # a twentieth (3DGS's share) of the colour rate it was measured with
    camera_rotation_lr: float = 1e-3
    camera_translation_lr: float = 3e-4
    patience: int = 20
    tolerance: float = 1e-2
    ssim_weight: float = 0.3
    splat_colours: bool = False
    choose_sh_degree: bool = True
    sh_tolerance: float = 1e-3
    seed: int = 0
    lr_decay_per_100_steps: float = 1.0
    densify: DensifySettings | None = None

    def __post_init__(self) -> None:
        if self.steps < 0:
            raise ValueError(f"steps={self.steps} must be >= 0")
        # imported here: the presets read these settings before torch is imported (pipeline.early_registration)
        from lumos3d_cli.losses.ssim import RADIUS

        if self.max_side <= 2 * RADIUS:
            raise ValueError(f"max_side={self.max_side}: SSIM needs images of at least {2 * RADIUS + 1} pixels")
        if self.views_per_step < 1:
            raise ValueError(f"views_per_step={self.views_per_step} must be >= 1")
        if self.positions not in ("free", "ray", "fixed"):
            raise ValueError(f"positions={self.positions!r}: use 'free', 'ray' or 'fixed'")
        if not 0 <= self.ssim_weight <= 1:
            raise ValueError(f"ssim_weight={self.ssim_weight} must be in [0, 1]")
        if not 0 < self.lr_decay_per_100_steps <= 1:
            raise ValueError(f"lr_decay_per_100_steps={self.lr_decay_per_100_steps} must be in (0, 1]")
        if self.densify is not None and (self.positions != "free" or self.views_per_step != 1):
            raise ValueError("densification needs free positions and one view per step (each view's gradient)")
        if self.patience < 1 or self.tolerance < 0:
            raise ValueError(f"patience={self.patience} must be >= 1 and tolerance={self.tolerance} >= 0")
