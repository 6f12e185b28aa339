"""What a restore reads and writes, by path: its photos (less an earlier restore's own outputs
among them) and its output set. Needs neither torch nor an image reader, so that the command
refuses a bad command line before the libraries load (about 2 s)."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.image_files import list_images
from lumos3d_cli.io.manifest import Manifest
from lumos3d_cli.io.output_set import OutputSet

logger = logging.getLogger(__name__)

# output format -> (file suffix, bit depth; 0 for linear EXR)
VIEW_FORMATS = {"png": (".png", 8), "png16": (".png", 16), "exr": (".exr", 0)}


def check_view_format(output_format: str) -> None:
    if output_format not in VIEW_FORMATS:
        raise InputError(f"{output_format!r}: use one of {', '.join(VIEW_FORMATS)}", parameter="output_format")


def check_lpips_weights(lpips_weights: Path | str | None, reference: Path | str | None) -> None:
    """LPIPS weights score the restored views against references: without them they would be
    ignored, so they are refused instead."""
    if lpips_weights is not None and reference is None:
        raise InputError(f"{lpips_weights}: LPIPS is scored against reference images; give references or leave the "
                         "weights out", parameter="lpips_weights")


def list_photos(photos: Path | str | Sequence[Path | str]) -> list[Path]:
    """The photos of a restore (`io.image_files.list_images`), less the images an earlier restore
    wrote among them (its contact sheet, when its output folder was the photo folder): the
    folder's manifest names them (io/manifest.py), and they are no photos of the scene."""
    paths = list_images(photos)
    manifests: dict[Path, Manifest] = {}
    ours = [path for path in paths if getattr(manifests.setdefault(path.parent, Manifest.read(path.parent)).files.get(
        path.name), "command", None) == "restore"]
    if ours:
        logger.info("not photos: %s, written by an earlier restore", ", ".join(str(path) for path in ours))
    kept = [path for path in paths if path not in ours]
    if not kept:
        raise InputError(f"{', '.join(str(path) for path in ours)}: written by an earlier restore, not photos; give the photos",
                         parameter="photos")
    return kept


# The files beside the scene, and the folders of lumos3d's own (they hold nothing else).
SIDE_FILES = ("cameras.json", "contact_sheet.png", "preview.glb", "summary.json")
OWN_FOLDERS = ("restored", "colmap")


def restore_outputs(scene_path: Path | str, inputs: Sequence[Path | str | None] = (), video: Path | str | None = None) -> OutputSet:
    """The outputs of a restore into `scene_path`'s folder (and `video`), kept clear of `inputs`:
    the photos and the folders given for them, the camera file, the references, the checkpoint.
    `check()` it before the work; `write_restored_scene` writes through it."""
    scene_path = Path(scene_path)
    if scene_path.suffix.lower() != ".ply":
        raise InputError(f"{scene_path}: the scene file must end in .ply", parameter="output")
    outputs = OutputSet(scene_path.parent, "restore", f"restore {scene_path.name}", inputs)
    for name in (scene_path.name, *SIDE_FILES):
        outputs.add_file(name)
    for name in OWN_FOLDERS:
        outputs.add_folder(name)
    if video is not None:
        outputs.add_elsewhere(Path(video), f"video {Path(video).name}")
    return outputs
