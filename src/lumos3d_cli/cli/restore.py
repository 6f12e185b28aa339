"""`lumos3d restore`: photos taken in the dark (or over-exposed) -> a restored 3D Gaussian scene,
its cameras, the restored views, a contact sheet, a preview and a summary. The job itself is
`pipeline.restore.restore`; this module parses options, shows progress and prints the result."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from lumos3d_cli.cli import preset_options
from lumos3d_cli.cli.console import ProgressBars, print_json, progress_bar, say
from lumos3d_cli.cli.interrupts import library_imports
from lumos3d_cli.cli.view import serve_until_stopped
from lumos3d_cli.data.modes import MODES
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.output_paths import check_output_path
from lumos3d_cli.io.scene_photos import list_photos
from lumos3d_cli.pipeline.choices import DEFAULT_RESTORE_PRESET, GEOMETRY_SOURCES
from lumos3d_cli.pipeline.restore_paths import check_lpips_weights, check_view_format, restore_outputs
from lumos3d_cli.viewer.availability import require_viser
from lumos3d_cli.viewer.defaults import DEFAULT_HOST, DEFAULT_MAX_SPLATS, DEFAULT_PORT
from lumos3d_cli.viewer.port import require_free_port

if TYPE_CHECKING:
    from lumos3d_cli.pipeline.restore import RestoredScene

EXAMPLES = """
  lumos3d restore photos/ -o out/scene.ply
  lumos3d restore dark/ -o out/scene.ply --preset best --reference bright/ --lpips-weights vgg16-397923af.pth
  lumos3d restore dark/ -o out/scene.ply --poses transforms.json
  lumos3d restore raw/*.dng -o out/scene.ply --checkpoint lumos3d.safetensors --output-format exr
  lumos3d restore dark/ -o out/scene.ply --video out/orbit.mp4 --view
"""


def restore_command(
    photos: list[Path] = typer.Argument(..., help="A folder or files: photos, camera RAW, EXR."),
    output: Path = typer.Option(..., "--output", "-o", help="The scene file to write (.ply); everything else goes beside it."),
    checkpoint: Path | None = typer.Option(None, "--checkpoint", help="Model weights (default: the bundled model of --mode)."),
    preset: str = typer.Option(DEFAULT_RESTORE_PRESET, "--preset", help="Speed/accuracy: fast, balanced or best."),
    mode: str = typer.Option("low-light", "--mode", help=f"One of: {', '.join(MODES)}."),
    geometry: str = typer.Option("auto", "--geometry", help=f"Cameras from: {', '.join(GEOMETRY_SOURCES)} (auto: sfm when it registers most views, else network)."),
    poses: Path | None = typer.Option(None, "--poses", help="Known cameras: a transforms.json, a COLMAP model folder (text or binary), a folder of LOM transforms_*.json, or a scene folder holding one (matched by file stem)."),
    max_views: int | None = typer.Option(None, "--max-views", help="Views the network sees (default: the preset's)."),
    refine_steps: int | None = preset_options.REFINE_STEPS,
    max_gaussians: int | None = preset_options.MAX_GAUSSIANS,
    gaussian_grid: float | None = preset_options.GAUSSIAN_GRID,
    exposure_prior: float | None = preset_options.EXPOSURE_PRIOR,
    exposure_key: str | None = preset_options.EXPOSURE_KEY,
    fill_unobserved: bool = preset_options.FILL_UNOBSERVED,
    densify: bool | None = preset_options.DENSIFY,
    depth_sweep: bool | None = preset_options.DEPTH_SWEEP,
    denoise: bool = preset_options.DENOISE_PHOTO,
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    reference: Path | None = typer.Option(None, "--reference", help="Normal-light photos of the same views (metrics)."),
    lpips_weights: Path | None = typer.Option(None, "--lpips-weights", help="torchvision vgg16 weights for LPIPS."),
    output_format: str = typer.Option("png", "--output-format", help="Restored views as png (8-bit), png16 or exr (linear)."),
    video: Path | None = typer.Option(None, "--video", help="Also write an orbit of the restored scene (.mp4 H.264 or .gif)."),
    view: bool = typer.Option(False, "--view", help="Open the result in the browser viewer when done (Ctrl-C stops it)."),
    port: int | None = typer.Option(None, "--port", show_default=False,
                                    help=f"The viewer's port with --view (0: any free port; default {DEFAULT_PORT})."),
    json_output: bool = typer.Option(False, "--json", help="Print the summary as JSON on stdout."),
) -> None:
    """Restore a 3D scene from unposed low-light or over-exposed photos."""
    if output.suffix.lower() != ".ply":
        raise InputError(f"{output}: the scene file must end in .ply", parameter="output")
    check_output_path(output, "output")
    check_output_path(video, "video")
    check_view_format(output_format)
    check_lpips_weights(lpips_weights, reference)
    if port is not None and not view:  # it would be ignored: the restore serves nothing without --view
        raise InputError(f"{port}: the viewer's port is used only with --view; add --view, or leave --port out", parameter="port")
    port = DEFAULT_PORT if port is None else port
    if view:  # refused before the restore, not after it has written a scene no viewer can show
        require_viser()
        require_free_port(DEFAULT_HOST, port)
    # Everything the outputs must stay clear of; checked, with what is already in the way, before any
    # work (and before the libraries load: a refusal ends at once), and again while the output
    # folder is held against other runs (io/output_set.py).
    paths = list_photos(photos)  # listed once: what the folder skips is said once
    inputs = [*paths, *photos, poses, reference, checkpoint, lpips_weights]
    outputs = restore_outputs(output, inputs, video)
    outputs.check()
    # The job's modules import torch, pycolmap, trimesh, viser and imageio-ffmpeg (seconds): imported
    # here, when the command runs, so that `--help` and a refused command line stay fast. Where
    # structure-from-motion needs nothing from the network, it starts before torch is imported
    # (pipeline/early_registration.py), on photos read once for the whole job. The output folder is
    # held from before that start: a second run into it was refused only once the first had
    # reached its network pass, after a minute of duplicated work.
    early = None
    with outputs.reserved():
        try:
            with library_imports():
                from lumos3d_cli.io.video import video_kind
                from lumos3d_cli.pipeline.early_registration import start_early_registration
                from lumos3d_cli.pipeline.presets import get_restore_preset

                if video is not None:  # refused before structure-from-motion starts, not seconds into it
                    video_kind(video)
                early = start_early_registration(paths, get_restore_preset(preset), geometry, poses)
                from lumos3d_cli.pipeline.orbit_video import DEFAULT_ORBIT_FRAMES
                from lumos3d_cli.pipeline.restore import restore
                from lumos3d_cli.pipeline.restore_outputs import write_restored_scene
            with progress_bar() as bars:
                scene = restore(
                    paths, mode=mode, checkpoint=checkpoint, preset=preset, geometry=geometry, poses=poses,
                    max_views=max_views, refine_steps=refine_steps, max_gaussians=max_gaussians,
                    gaussian_grid=gaussian_grid, exposure_prior=exposure_prior, exposure_key=exposure_key,
                    fill_unobserved=fill_unobserved, densify=densify, depth_sweep=depth_sweep, denoise_photo=denoise,
                    device=device, reference=reference, lpips_weights=lpips_weights, progress=ProgressBars(bars),
                    early_registration=early,
                )
                frames = bars.add_task("orbit video", total=DEFAULT_ORBIT_FRAMES, visible=video is not None)
                summary = write_restored_scene(scene, output, output_format, video, inputs,
                                               on_video_frame=lambda: bars.advance(frames))
        finally:
            if early is not None:  # a refused or interrupted job stops COLMAP and removes its folder
                early.close()
    if json_output:
        print_json(summary)
    else:
        _report(scene, summary, output, video)
    if view:
        serve_until_stopped(output.parent, DEFAULT_HOST, port, DEFAULT_MAX_SPLATS,
                            "the viewer stopped; the restore's outputs are written")


def _report(scene: RestoredScene, summary: dict, output: Path, video: Path | None) -> None:
    """What was written, on stderr (stdout stays for --json)."""
    geometry_report = summary["geometry"]
    if video is not None:
        say(f"orbit video: {video}")
    say(f"restored {len(scene.names)} view(s) with {geometry_report['source']} cameras: {output} "
        f"({len(scene.gaussians):,} Gaussians), views in {output.parent / 'restored'}, contact sheet "
        f"{output.parent / 'contact_sheet.png'}")
    mean = (summary.get("metrics") or {}).get("mean") or {}
    scores = [f"{label} {mean[key]:.{digits}f}" for key, label, digits in
              (("psnr", "PSNR", 2), ("ssim", "SSIM", 3), ("lpips", "LPIPS", 3)) if mean.get(key) is not None]
    if scores:  # --reference: the mean over the views (each view's in summary.json)
        say(f"against --reference: {', '.join(scores)} (mean of the views; each view's in summary.json)")
