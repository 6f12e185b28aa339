"""What a restore writes, by path: its output set (its photos: io/scene_photos.py). Needs neither torch nor an image reader, so that the command
refuses a bad command line before the libraries load (about 2 s)."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

from lumos3d_cli.errors import InputError
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
