"""Which files are images, in which order: suffix sets, natural sorting, folder listing."""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Sequence
from pathlib import Path

from lumos3d_cli.errors import InputError, listed

logger = logging.getLogger(__name__)

PHOTO_SUFFIXES = frozenset({".jpg", ".jpeg", ".png", ".tif", ".tiff", ".webp", ".bmp"})
HDR_SUFFIXES = frozenset({".exr", ".hdr"})
RAW_SUFFIXES = frozenset(
    {
        ".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".raf", ".orf",
        ".rw2", ".pef", ".srw", ".x3f", ".3fr", ".iiq", ".erf", ".kdc", ".dcr", ".mrw", ".mos",
        ".rwl", ".raw",
    }
)
IMAGE_SUFFIXES = PHOTO_SUFFIXES | HDR_SUFFIXES | RAW_SUFFIXES
# Images lumos3d does not read: in a folder they are named when skipped, not passed over in
# silence (a phone's HEIC photos among its JPEGs would otherwise drop views unnoticed).
UNREAD_IMAGE_SUFFIXES = frozenset({".heic", ".heif", ".avif", ".gif", ".jxl", ".jp2", ".psd", ".svg", ".ico"})

_DIGITS = re.compile(r"(\d+)")


def natural_sort_key(path: Path | str) -> tuple:
    """Sort key that orders embedded numbers by value: `2.jpg` before `10.jpg`."""
    name = Path(path).name
    return tuple((0, int(part), "") if part.isdigit() else (1, 0, part.lower()) for part in _DIGITS.split(name) if part)


def image_kind(path: Path) -> str:
    """'photo', 'hdr' or 'raw' from the file suffix; InputError for anything else."""
    suffix = path.suffix.lower()
    if suffix in PHOTO_SUFFIXES:
        return "photo"
    if suffix in HDR_SUFFIXES:
        return "hdr"
    if suffix in RAW_SUFFIXES:
        return "raw"
    supported = " ".join(sorted(IMAGE_SUFFIXES))
    raise InputError(f"{path}: unsupported file type '{path.suffix}'; use one of: {supported}")


def list_images(inputs: Path | str | Sequence[Path | str]) -> list[Path]:
    """Expand a folder (its image files, naturally sorted) or a list of files and folders.

    Explicitly named files must exist and have a supported suffix; inside folders, files
    that are not images (and hidden files) are skipped. The same photo twice is an InputError
    (see `check_distinct`).
    """
    items = [inputs] if isinstance(inputs, (str, Path)) else list(inputs)
    if not items:
        raise InputError("no input images given; pass a folder or image files")
    paths: list[Path] = []
    for item in items:
        path = Path(item)
        if path.is_dir():
            entries = [p for p in path.iterdir() if not p.name.startswith(".")]
            named = [p for p in entries if p.suffix.lower() in IMAGE_SUFFIXES]
            found = [p for p in named if p.is_file()]
            unreadable = sorted(p.name for p in named if not p.is_file() and not p.is_dir())
            if unreadable:
                logger.warning("%s: skipped %s: named as images but not files (a broken link, a pipe or a device)",
                               path, ", ".join(unreadable))
            unread = sorted((p.name for p in entries if p.suffix.lower() in UNREAD_IMAGE_SUFFIXES), key=natural_sort_key)
            if not found:
                also = f"; {listed(unread)} cannot be read: convert them to JPEG or PNG" if unread else ""
                holding = sorted((p.name for p in entries if p.is_dir() and _holds_images(p)), key=natural_sort_key)
                those = "its subfolder {} does: give that folder" if len(holding) == 1 else \
                    "its subfolders {} do: give one of them"
                inside = f"; {those.format(listed(holding))}" if holding and not unread else ""
                raise InputError(f"{path}: folder holds no images ({', '.join(sorted(IMAGE_SUFFIXES))}){also}{inside}")
            if unread:
                logger.warning("%s: skipped %s: a format lumos3d does not read; convert to JPEG or PNG to include them",
                               path, listed(unread))
            paths.extend(sorted(found, key=natural_sort_key))
        elif path.is_file():
            image_kind(path)
            paths.append(path)
        elif path.exists():
            raise InputError(f"{path}: is not a file (a pipe, a device or a socket); pass an image file or a folder")
        else:
            raise InputError(f"{path}: no such file or folder")
    for path in paths:
        _require_text_name(path)
    check_distinct(paths)
    return paths


def _require_text_name(path: Path) -> None:
    """InputError when `path` is no UTF-8 text (a Latin-1 `café.jpg` from an old archive): the
    image libraries take file names as text and cannot open it."""
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        shown = os.fsencode(path).decode("utf-8", "backslashreplace")
        raise InputError(f"{shown}: the file name is not UTF-8 text, which the image libraries cannot open; "
                         "rename the file") from None


def _holds_images(folder: Path) -> bool:
    """Whether `folder` holds an image file (not looking further down)."""
    try:
        return any(p.suffix.lower() in IMAGE_SUFFIXES and p.is_file() and not p.name.startswith(".")
                   for p in folder.iterdir())
    except OSError:
        return False


def check_distinct(paths: Sequence[Path]) -> None:
    """InputError when a file comes twice (named twice, or in a folder also given) or two files
    share a name stem in any case (`a/1.jpg` and `b/1.jpg`, `A.jpg` and `a.jpg`, or a camera's
    `IMG_1.CR2` + `IMG_1.JPG` pair):
    views and their outputs are named by the stem, so one would overwrite the other. An error
    rather than dropping one: which of two same-named photos is meant is the user's call."""
    seen: dict[str, Path] = {}
    for path in paths:
        earlier = seen.get(path.stem.casefold())  # in any case: A.jpg and a.jpg share restored/a.png on macOS
        if earlier is None:
            seen[path.stem.casefold()] = path
            continue
        if earlier.resolve() == path.resolve():
            raise InputError(f"{path}: the same photo is given twice; pass each photo once")
        raise InputError(
            f"{earlier} and {path}: two photos named '{path.stem}' (views and outputs are named by the file "
            "name, so one would overwrite the other); pass only one of them or rename one"
        )
