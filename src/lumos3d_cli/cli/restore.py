"""`lumos3d restore`: photos taken in the dark (or over-exposed) -> a restored 3D Gaussian scene,
its cameras, the restored views, a contact sheet, a preview and a summary. The job itself is
`pipeline.restore.restore`; this module parses options, shows progress and prints the result."""

from __future__ import annotations

from pathlib import Path

import typer

from lumos3d_cli.cli.console import ProgressBars, print_json, progress_bar, say
from lumos3d_cli.data.degradations import MODES
from lumos3d_cli.errors import InputError
from lumos3d_cli.pipeline.presets import DEFAULT_RESTORE_PRESET
from lumos3d_cli.pipeline.restore import restore
from lumos3d_cli.pipeline.restore_outputs import check_view_format, write_restored_scene
from lumos3d_cli.pipeline.scene_geometry import GEOMETRY_SOURCES

EXAMPLES = """
  lumos3d restore photos/ -o out/scene.ply
  lumos3d restore dark/ -o out/scene.ply --preset best --reference bright/ --lpips-weights vgg16-397923af.pth
  lumos3d restore dark/ -o out/scene.ply --poses transforms.json
  lumos3d restore raw/*.dng -o out/scene.ply --checkpoint lumos3d.safetensors --output-format exr
"""


def restore_command(
    photos: list[Path] = typer.Argument(..., help="A folder or files: photos, camera RAW, EXR."),
    output: Path = typer.Option(..., "--output", "-o", help="The scene file to write (.ply); everything else goes beside it."),
    checkpoint: Path | None = typer.Option(None, "--checkpoint", help="Model weights (default: the bundled model of --mode)."),
    preset: str = typer.Option(DEFAULT_RESTORE_PRESET, "--preset", help="Speed/accuracy: fast, balanced or best."),
    mode: str = typer.Option("low-light", "--mode", help=f"One of: {', '.join(MODES)}."),
    geometry: str = typer.Option("auto", "--geometry", help=f"Cameras from: {', '.join(GEOMETRY_SOURCES)} (auto: sfm when it registers most views, else network)."),
    poses: Path | None = typer.Option(None, "--poses", help="Known cameras: a transforms.json or a COLMAP model folder (matched by file stem)."),
    max_views: int | None = typer.Option(None, "--max-views", help="Views the network sees (default: the preset's)."),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    reference: Path | None = typer.Option(None, "--reference", help="Normal-light photos of the same views (metrics)."),
    lpips_weights: Path | None = typer.Option(None, "--lpips-weights", help="torchvision vgg16 weights for LPIPS."),
    output_format: str = typer.Option("png", "--output-format", help="Restored views as png (8-bit), png16 or exr (linear)."),
    json_output: bool = typer.Option(False, "--json", help="Print the summary as JSON on stdout."),
) -> None:
    """Restore a 3D scene from unposed low-light or over-exposed photos."""
    if output.suffix.lower() != ".ply":
        raise InputError(f"{output}: the scene file must end in .ply", parameter="output")
    check_view_format(output_format)
    with progress_bar() as bars:
        scene = restore(
            photos, mode=mode, checkpoint=checkpoint, preset=preset, geometry=geometry, poses=poses,
            max_views=max_views, device=device, reference=reference, lpips_weights=lpips_weights,
            progress=ProgressBars(bars),
        )
        summary = write_restored_scene(scene, output, output_format)
    if json_output:
        print_json(summary)
        return
    geometry_report = summary["geometry"]
    say(f"restored {len(scene.names)} view(s) with {geometry_report['source']} cameras: {output} "
        f"({len(scene.gaussians):,} Gaussians), views in {output.parent / 'restored'}, contact sheet "
        f"{output.parent / 'contact_sheet.png'}")
