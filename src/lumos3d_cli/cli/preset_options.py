"""The options of `restore` and `eval` that override a preset's settings (pipeline.presets)."""

from __future__ import annotations

import typer

from lumos3d_cli.pipeline.choices import EXPOSURE_KEYS

REFINE_STEPS = typer.Option(
    None, "--refine-steps",
    help="Test-time refinement steps after the forward pass, exactly (default: the preset's, in balanced and best "
         "at least one per photo up to twice its steps; 0: none).")
MAX_GAUSSIANS = typer.Option(
    None, "--max-gaussians", help="Keep at most this many Gaussians, the ones the views draw most (default: all that the views show).")
GAUSSIAN_GRID = typer.Option(
    None, "--gaussian-grid", help="Pixel Gaussians per network pixel along each side, 1 to 4 (default: the preset's; at most the photos' resolution).")
EXPOSURE_PRIOR = typer.Option(
    None, "--exposure-prior", help="How far the scene's overall brightness moves towards a well-exposed key, 0 (the model's own) to 1 (default: 0.75 in low light, 0.5 over-exposed).")
EXPOSURE_KEY = typer.Option(
    None, "--exposure-key",
    help=f"The brightness the exposure prior aims at: {' or '.join(EXPOSURE_KEYS)} (content, the default: predicted from what the scene shows; fixed: mean sRGB 0.45 for every scene).")
DENOISE_PHOTO = typer.Option(
    True, "--denoise/--no-denoise",
    help="Views restored in 2D (a single photo; photos no geometry places): remove the sensor noise their restoration amplified, in proportion to its measured level.")
DENSIFY = typer.Option(
    None, "--densify/--no-densify",
    help="Split and clone the Gaussians where the views disagree with the scene during refinement (default: the preset's; best densifies).")
DEPTH_SWEEP = typer.Option(
    None, "--depth-sweep/--no-depth-sweep",
    help="Refine the registered depth where neighbouring photos agree (a plane sweep) before fusing (default: the preset's; every preset sweeps).")
FILL_UNOBSERVED = typer.Option(
    True, "--fill-unobserved/--black-unobserved",
    help="Fill the restored views' pixels that no Gaussian covers from the render around them, or leave them black.")
