"""Find and read camera files of any supported format; write the ones we export."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import warn_if_mid_commit
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.colmap import is_colmap_model, read_colmap_model
from lumos3d_cli.io.transforms_json import read_transforms_json

logger = logging.getLogger(__name__)

_HINT = ("pass a transforms.json, a COLMAP model folder (text or binary), a folder of LOM-style "
         "transforms_{train,val,test}.json or a scene folder holding one of those")


LOM_SPLITS = ("test", "train", "val")


def transforms_splits(folder: Path) -> list[Path]:
    """A LOM-style folder's transforms_{test,train,val}.json that exist (none where a
    transforms.json is there: that file is the scene's cameras)."""
    if (folder / "transforms.json").is_file():
        return []
    return [folder / f"transforms_{split}.json" for split in LOM_SPLITS if (folder / f"transforms_{split}.json").is_file()]


def read_transforms_splits(folder: Path, warn_on_distortion: bool = True) -> Cameras:
    """The frames of `folder`'s splits together, in the order test, train, val; a frame in two
    splits (LOM's buu lists 1.JPG in test and val) once, where both give it the same camera. The
    splits share one lens: its distortion is warned of once."""
    parts = [read_transforms_json(split, warn_on_distortion and index == 0)
             for index, split in enumerate(transforms_splits(folder))]
    cameras = Cameras(torch.cat([p.extrinsics for p in parts]), torch.cat([p.intrinsics for p in parts]),
                      [s for p in parts for s in p.sizes], [n for p in parts for n in p.names])
    first: dict[str, int] = {}
    keep = []
    for index, name in enumerate(cameras.names):
        earlier = first.setdefault(name, index)
        if earlier == index or not (torch.equal(cameras.extrinsics[earlier], cameras.extrinsics[index])
                                    and torch.equal(cameras.intrinsics[earlier], cameras.intrinsics[index])):
            keep.append(index)
    return cameras[keep] if len(keep) < len(cameras) else cameras


def find_camera_source(path: Path | str) -> Path | None:
    """The camera file or folder that `path` names or holds, or None.

    Accepted: a `.json` file; a COLMAP model folder, text or binary (or one of its cameras/images
    files); a scene folder with `sparse/0/`, `colmap/`, `transforms.json` or `cameras.json` (in
    that order: a COLMAP model first, as `restore --poses` has always read a scene folder, so that
    `render --poses` of the same folder uses the same cameras, where a transforms.json made from
    that model by colmap2nerf is re-centred and rescaled); a folder of LOM-style
    transforms_{test,train,val}.json (read together).
    """
    path = Path(path)
    if path.is_file():
        if path.suffix.lower() == ".json":
            return path
        if path.name in ("cameras.txt", "images.txt", "cameras.bin", "images.bin"):
            return path.parent if is_colmap_model(path.parent) else None
        return None
    return next(camera_sources(path), None)


def camera_sources(path: Path | str) -> Iterator[Path]:
    """Every camera file or folder that `path` names or holds, in `find_camera_source`'s order,
    one at a time (a reader may fall back to the next when one cannot be read; the first costs no
    look at the others). A candidate that cannot be looked at (no permission) counts as absent."""
    path = Path(path)
    if path.is_file():
        found = find_camera_source(path)
        if found is not None:
            yield found
        return
    if not path.is_dir():
        return
    if is_colmap_model(path):
        yield path
        return
    for candidate in (path / "sparse" / "0", path / "colmap", path / "transforms.json", path / "cameras.json"):
        try:
            found = find_camera_source(candidate) if candidate.exists() else None
        except OSError as error:  # a folder without read permission: as if it were not there
            logger.warning("%s: cannot be read (%s); not looked at for cameras", candidate, error.strerror)
            continue
        if found is not None:
            yield found
    if transforms_splits(path):
        yield path


def read_cameras(path: Path | str, warn_on_distortion: bool = True) -> Cameras:
    """Read cameras from any supported source (see `find_camera_source`)."""
    source = find_camera_source(path)
    if source is None:
        if not Path(path).exists():
            raise InputError(f"{path}: no such file or folder")
        raise InputError(f"{path}: no cameras found; {_HINT}")
    warn_if_mid_commit(source)
    if source.is_dir():
        if is_colmap_model(source):
            return read_colmap_model(source, warn_on_distortion)
        return read_transforms_splits(source, warn_on_distortion)
    return read_transforms_json(source, warn_on_distortion)
