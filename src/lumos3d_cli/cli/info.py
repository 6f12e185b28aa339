"""`lumos3d info`: summarise a Gaussian scene, a checkpoint, a camera file or an image folder."""

from __future__ import annotations

import logging
from pathlib import Path

import typer
from rich.table import Table

from lumos3d_cli.cli.console import print_json, progress_bar, stdout_console
from lumos3d_cli.cli.interrupts import library_imports
from lumos3d_cli.data.lom_layout import DEGRADED_FOLDERS, REFERENCE_FOLDER, is_lom_scene
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.image_files import IMAGE_SUFFIXES, list_images
from lumos3d_cli.model.architectures import ARCHITECTURES

# restore refuses a photo smaller than one network patch (pipeline.restore.check_photo_contents)
SMALLEST_PHOTO_SIDE = min(architecture.patch_size for architecture in ARCHITECTURES.values())

EXAMPLES = """
  lumos3d info out/scene.ply
  lumos3d info scenes/kitchen            [dim]# images/ and sparse/0 of a scene folder[/dim]
  lumos3d info transforms.json --json
  lumos3d info photos/ --deep            [dim]# decode every image: which will not load or restore[/dim]
"""


def _has_images(folder: Path) -> bool:
    return any(p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".") for p in folder.iterdir() if p.is_file())


def _image_summary(paths: list[Path], deep: bool) -> dict:
    """summarize_image_files, plus with `deep` the files that will not load and why (every image
    decoded, as restore would) and those too small for the network (`too_small`). Without it only the headers are read: decoding takes about 17 ms
    per 0.2-megapixel photo of LOM buu here, seconds per 24-megapixel photo or RAW file."""
    with library_imports():
        from lumos3d_cli.io.images import probe_image, read_image
        from lumos3d_cli.io.summaries import summarize_image_files
    if not deep:
        summary = summarize_image_files(paths)
        summary["pixels"] = "not decoded; --deep decodes every image to find those that will not load"
        return summary
    unreadable, too_small, readable = {}, {}, []
    for path in paths:  # a header that does not read is one more file that will not load, not the end
        try:
            probe_image(path)
            readable.append(path)
        except InputError as error:
            unreadable[path.name] = str(error).removeprefix(f"{path}: ")
    summary = summarize_image_files(readable) if readable else {"kind": "images"}
    summary["count"] = len(paths)
    with progress_bar() as progress:
        task = progress.add_task("decode", total=len(readable))
        for path in readable:
            try:
                height, width = read_image(path).pixels.shape[:2]
                if min(width, height) < SMALLEST_PHOTO_SIDE:
                    too_small[path.name] = (f"{width}x{height} pixels, too small for the network (at least "
                                            f"{SMALLEST_PHOTO_SIDE} pixels a side)")
            except InputError as error:  # NonFiniteError included: NaN or Inf samples
                unreadable[path.name] = str(error).removeprefix(f"{path}: ")
            progress.advance(task)
    summary["will_not_load"] = {path.name: unreadable[path.name] for path in paths if path.name in unreadable}
    summary["too_small"] = too_small
    return summary


def _refuse_unreadable(summaries: list[dict]) -> None:
    """After the table: exit 2 with one line naming the images that will not load or are too
    small to restore."""
    for summary in summaries:
        refused = {**summary.get("will_not_load", {}), **summary.get("too_small", {})}
        if refused:
            shown = "; ".join(f"{name} ({reason})" for name, reason in list(refused.items())[:3])
            more = f"; and {len(refused) - 3} more" if len(refused) > 3 else ""
            raise InputError(f"{len(refused)} of {summary['count']} images will not load or restore: {shown}{more}")


_COLMAP_FILES = ("cameras", "images", "points3D", "frames", "rigs")  # a COLMAP model's files, text or binary


def collect_summaries(path: Path, deep: bool = False) -> list[dict]:
    """Every summary that applies to `path`; `deep` decodes images (see `_image_summary`)."""
    # The readers import torch, pycolmap, OpenCV and the image libraries (seconds): imported here
    # and in `_image_summary`, when the command runs, so that `--help` stays fast.
    with library_imports():
        from lumos3d_cli.io.atomic import warn_if_mid_commit
        from lumos3d_cli.io.camera_files import find_camera_source
        from lumos3d_cli.io.colmap import is_colmap_model
        from lumos3d_cli.io.summaries import summarize_camera_file, summarize_gaussian_file
        from lumos3d_cli.io.weight_files import FOLDER_FILES
        from lumos3d_cli.model.bundled_models import BUNDLED_MODELS, resolve_checkpoint
        from lumos3d_cli.model.checkpoints import summarize_checkpoint
    if not path.exists():
        if str(path) in BUNDLED_MODELS:  # `info low-light`: a bundled model by name, as restore --checkpoint takes it
            return [summarize_checkpoint(resolve_checkpoint(str(path)))]
        raise InputError(f"{path}: no such file or folder")
    if not (path.is_file() or path.is_dir()):
        raise InputError(f"{path}: is neither a file nor a folder (a device, pipe or socket); pass a .ply, checkpoint, "
                         "camera file, image or folder")
    warn_if_mid_commit(path)  # a killed run's half-moved outputs would be summarised as one set
    if path.is_file():
        suffix = path.suffix.lower()
        if suffix == ".ply":
            return [summarize_gaussian_file(path)]
        if path.stem in _COLMAP_FILES and suffix in (".bin", ".txt") and is_colmap_model(path.parent):
            return [summarize_camera_file(path.parent)]  # points3D.bin is no checkpoint: the model it belongs to
        if suffix in (".safetensors", ".pt", ".pth", ".bin"):
            return [summarize_checkpoint(path)]
        if suffix in IMAGE_SUFFIXES:
            return [_image_summary([path], deep)]
        if find_camera_source(path) is not None:
            return [summarize_camera_file(path)]
        raise InputError(f"{path}: cannot summarise '{path.suffix}' files; pass a .ply, checkpoint, camera file, image or folder")
    # a restore's output folder: its scene (its PNGs are the contact sheet; restored/ holds the views)
    scenes = _files_in(path, (".ply",))
    # one .ply that is no Gaussian scene (a mesh beside it) does not hide the others
    summaries = _each_summary(scenes, summarize_gaussian_file)
    image_folders = [path] if _has_images(path) and not scenes else []
    if not image_folders and (path / "images").is_dir() and _has_images(path / "images"):
        image_folders = [path / "images"]
    if not image_folders and is_lom_scene(path):  # the photos of each lighting
        image_folders = [path / name for name in (REFERENCE_FOLDER, *DEGRADED_FOLDERS.values())
                         if (path / name).is_dir() and _has_images(path / name)]
    for folder in image_folders:
        summaries.append({**_image_summary(list_images(folder), deep), "path": str(folder)})
    if find_camera_source(path) is not None:
        summaries.append(summarize_camera_file(path))
    if any((path / name).is_file() for name in FOLDER_FILES):  # a checkpoint folder, as restore --checkpoint takes one
        summaries.append(summarize_checkpoint(path))
    elif not summaries:  # a folder of weight files (a training run's final.safetensors, a converted file): each
        summaries = _each_summary(_files_in(path, (".safetensors", ".pt", ".pth")), summarize_checkpoint)
    if not summaries:
        raise InputError(f"{path}: holds no images, cameras, checkpoint or .ply; nothing to summarise")
    return summaries


def _files_in(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    """The folder's files (not hidden ones) with one of `suffixes`, sorted."""
    return sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in suffixes)


def _each_summary(files: list[Path], summarize) -> list[dict]:
    """`summarize` of each of `files`; one that cannot be summarised is named in a warning and
    left out, unless it is the only one (then its error is the command's)."""
    summaries = []
    for file in files:
        try:
            summaries.append(summarize(file))
        except InputError as error:
            if len(files) == 1:
                raise
            logging.getLogger(__name__).warning("%s; left out of the summary", error)
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
    deep: bool = typer.Option(False, "--deep", help="Decode every image (slow) and list those that will not load or restore."),
    json_output: bool = typer.Option(False, "--json", help="Print the summary as JSON on stdout."),
) -> None:
    """Summarise a Gaussian scene, a model checkpoint (refused if it holds NaN/Inf), cameras or images.

    With --deep, images that will not load (or are too small to restore) are listed and the
    command exits with 2."""
    summaries = collect_summaries(path, deep)
    if json_output:
        print_json(summaries[0] if len(summaries) == 1 else {"path": str(path), "summaries": summaries})
        _refuse_unreadable(summaries)
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
    _refuse_unreadable(summaries)
