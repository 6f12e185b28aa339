"""Find and read camera files of any supported format; write the ones we export."""

from __future__ import annotations

from pathlib import Path

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.colmap import read_colmap_model
from lumos3d_cli.io.transforms_json import read_transforms_json

_HINT = "pass a transforms.json, a COLMAP text model folder (cameras.txt + images.txt) or a scene folder"


def find_camera_source(path: Path | str) -> Path | None:
    """The camera file or COLMAP folder that `path` names or holds, or None.

    Accepted: a `.json` file; a folder or file inside a folder with cameras.txt + images.txt;
    a scene folder with `transforms.json`, `cameras.json` or `sparse/0/`.
    """
    path = Path(path)
    if path.is_file():
        if path.suffix.lower() == ".json":
            return path
        if path.name in ("cameras.txt", "images.txt"):
            return path.parent
        return None
    if not path.is_dir():
        return None
    if (path / "cameras.txt").is_file() and (path / "images.txt").is_file():
        return path
    for candidate in (path / "transforms.json", path / "cameras.json", path / "sparse" / "0", path / "colmap"):
        found = find_camera_source(candidate) if candidate.exists() else None
        if found is not None:
            return found
    return None


def read_cameras(path: Path | str) -> Cameras:
    """Read cameras from any supported source (see `find_camera_source`)."""
    source = find_camera_source(path)
    if source is None:
        if not Path(path).exists():
            raise InputError(f"{path}: no such file or folder")
        raise InputError(f"{path}: no cameras found; {_HINT}")
    if source.is_dir():
        return read_colmap_model(source)
    return read_transforms_json(source)
