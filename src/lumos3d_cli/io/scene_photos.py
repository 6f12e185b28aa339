"""The photos of a scene in a folder or list of files: the image files (`io.image_files`) less
the images an earlier restore wrote among them (its contact sheet, when its output folder was the
photo folder), which the folder's manifest names (io/manifest.py). Every reader of photo sets
(`restore`, `load_images`, `degrade`) lists them so."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import warn_if_mid_commit
from lumos3d_cli.io.image_files import list_images
from lumos3d_cli.io.manifest import Manifest

logger = logging.getLogger(__name__)


def list_photos(photos: Path | str | Sequence[Path | str]) -> list[Path]:
    """The photos in `photos` (a folder, or files), in order: `list_images` less an earlier
    restore's outputs (module docstring); InputError when nothing else is left."""
    paths = list_images(photos)
    for folder in dict.fromkeys(path.parent for path in paths):
        warn_if_mid_commit(folder)
    manifests = {folder: Manifest.read(folder) for folder in dict.fromkeys(path.parent for path in paths)}
    ours = [path for path in paths if getattr(manifests[path.parent].files.get(path.name), "command", None) == "restore"]
    if ours:
        logger.info("not photos: %s, written by an earlier restore", ", ".join(str(path) for path in ours))
    kept = [path for path in paths if path not in ours]
    if not kept:
        raise InputError(f"{', '.join(str(path) for path in ours)}: written by an earlier restore, not photos; give the photos")
    return kept
