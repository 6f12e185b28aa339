"""`lumos3d info`: summarise a Gaussian scene, a checkpoint, a camera file or an image folder."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from lumos3d_cli.cli.console import print_json, stdout_console
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.camera_files import find_camera_source
from lumos3d_cli.model.checkpoints import summarize_checkpoint
from lumos3d_cli.io.image_files import IMAGE_SUFFIXES, list_images
from lumos3d_cli.io.summaries import summarize_camera_file, summarize_gaussian_file, summarize_image_files

EXAMPLES = """
  lumos3d info out/scene.ply
  lumos3d info scenes/kitchen            [dim]# images/ and sparse/0 of a scene folder[/dim]
  lumos3d info transforms.json --json
"""


def _has_images(folder: Path) -> bool:
    return any(p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".") for p in folder.iterdir() if p.is_file())


def collect_summaries(path: Path) -> list[dict]:
    """Every summary that applies to `path`."""
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    if path.is_file():
        suffix = path.suffix.lower()
        if suffix == ".ply":
            return [summarize_gaussian_file(path)]
        if suffix in (".safetensors", ".pt", ".pth", ".bin"):
            return [summarize_checkpoint(path)]
        if suffix in IMAGE_SUFFIXES:
            return [summarize_image_files([path])]
        if find_camera_source(path) is not None:
            return [summarize_camera_file(path)]
        raise InputError(f"{path}: cannot summarise '{path.suffix}' files; pass a .ply, checkpoint, camera file, image or folder")
    summaries = []
    if _has_images(path):
        summaries.append(summarize_image_files(list_images(path)))
    elif (path / "images").is_dir() and _has_images(path / "images"):
        summaries.append(summarize_image_files(list_images(path / "images")))
    if find_camera_source(path) is not None:
        summaries.append(summarize_camera_file(path))
    if not summaries:
        raise InputError(f"{path}: holds no images, cameras or .ply; nothing to summarise")
    return summaries


def _format(value) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, list):
        return "[" + ", ".join(_format(v) for v in value) + "]"
    if isinstance(value, dict):
        return ", ".join(f"{k}: {_format(v)}" for k, v in value.items())
    return str(value)


def info_command(
    path: Path = typer.Argument(..., help="A .ply scene, a checkpoint, a camera file or COLMAP folder, an image or a folder."),
    json_output: bool = typer.Option(False, "--json", help="Print the summary as JSON on stdout."),
) -> None:
    """Summarise a Gaussian scene, a model checkpoint, cameras or images."""
    summaries = collect_summaries(path)
    if json_output:
        print_json(summaries[0] if len(summaries) == 1 else {"path": str(path), "summaries": summaries})
        return
    console = stdout_console()
    for summary in summaries:
        table = Table(title=f"{summary['kind']}: {summary.get('path', path)}", show_header=False, title_justify="left")
        table.add_column("field", style="bold")
        table.add_column("value")
        for key, value in summary.items():
            if key not in ("kind", "path"):
                table.add_row(key, _format(value))
        console.print(table)
