"""Gather what the viewer shows from a restore output folder (or a bare `.ply`).

A restore folder holds the scene `.ply`, cameras.json, restored/<photo stem>.<png|exr>,
colmap/points3D.txt (sparse points when structure-from-motion ran) and summary.json, whose
"input_paths" (when present) locate the original photos."""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.camera_files import find_camera_source, read_cameras
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.colmap import read_colmap_points
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.io.image_files import IMAGE_SUFFIXES
from lumos3d_cli.io.images import read_image, resize_image, to_srgb
from lumos3d_cli.io.ply import read_ply

logger = logging.getLogger(__name__)

# Long side of the photos drawn inside the camera frustums: enough to recognise the view, small
# enough that a few dozen of them (JPEG) load in a moment.
THUMBNAIL_SIZE = 320
_HINT = "pass a restore output folder (the folder of `lumos3d restore -o FOLDER/scene.ply`) or a .ply scene"


@dataclass
class SparseCloud:
    """xyz [P, 3] float64 world coordinates; rgb [P, 3] uint8."""

    xyz: np.ndarray
    rgb: np.ndarray


@dataclass
class ViewerScene:
    """Everything the viewer draws. Per-camera photo lists align with `cameras`; an entry is
    None where that photo is not available. thumbnails are [h, w, 3] uint8 sRGB."""

    scene_path: Path
    gaussians: Gaussians
    cameras: Cameras | None = None
    restored: list[np.ndarray | None] = field(default_factory=list)
    inputs: list[np.ndarray | None] = field(default_factory=list)
    points: SparseCloud | None = None
    summary: dict | None = None
    notes: list[str] = field(default_factory=list)  # what is missing, said in the panel


def thumbnail(path: Path, size: int = THUMBNAIL_SIZE) -> np.ndarray:
    """Any supported image file -> [h, w, 3] uint8 sRGB with its long side at most `size`."""
    pixels = to_srgb(read_image(path))
    height, width = pixels.shape[:2]
    factor = min(1.0, size / max(width, height))
    if factor < 1.0:
        pixels = resize_image(pixels, max(1, round(width * factor)), max(1, round(height * factor)))
    return np.round(np.clip(pixels, 0.0, 1.0) * 255).astype(np.uint8)


def _read_scene(path: Path) -> Gaussians:
    """The .ply's Gaussians; InputError for one that holds none (nothing to show)."""
    gaussians = read_ply(path)
    if len(gaussians) == 0:
        raise InputError(f"{path}: holds no Gaussians; there is nothing to view")
    return gaussians


def _thumbnails(paths: list[Path | None]) -> list[np.ndarray | None]:
    """`thumbnail` of each path (None: none, or one that cannot be read, with a warning naming it:
    the photos are what the viewer shows beside the scene, not the scene)."""
    found = []
    for path in paths:
        try:
            found.append(thumbnail(path) if path is not None else None)
        except InputError as error:
            logger.warning("%s; the viewer shows its view without it", error)
            found.append(None)
    return found


def _read_summary(folder: Path) -> dict | None:
    path = folder / "summary.json"
    if not path.is_file():
        return None
    try:
        summary = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise InputError(f"{path}: not readable JSON ({error}); restore the scene again or pass the .ply alone") from error
    if not isinstance(summary, dict):
        raise InputError(f"{path}: expected a JSON object; restore the scene again or pass the .ply alone")
    return summary


def _scene_file(folder: Path, summary: dict | None) -> Path:
    """The folder's scene: the one summary.json names, else its only .ply."""
    if summary is not None and isinstance(summary.get("scene"), str):
        named = folder / Path(summary["scene"]).name
        if named.is_file():
            return named
    plies = sorted(p for p in folder.glob("*.ply") if not p.name.startswith("."))
    if not plies:
        raise InputError(f"{folder}: no .ply scene in this folder; {_HINT}")
    if len(plies) > 1:
        raise InputError(f"{folder}: {len(plies)} .ply files ({', '.join(p.name for p in plies)}); pass the one to view")
    return plies[0]


def _restored_photo(folder: Path, name: str) -> Path | None:
    """restored/<stem of the input's name>.<any image suffix>."""
    stem = Path(name).stem
    for candidate in sorted((folder / "restored").glob(f"{stem}.*")):
        if candidate.suffix.lower() in IMAGE_SUFFIXES:
            return candidate
    return None


def _input_photos(folder: Path, summary: dict | None, cameras: Cameras) -> tuple[list[Path | None], str | None]:
    """The original photo of each camera from summary.json's "input_paths" (relative paths are
    relative to the folder), and a note when some or all are unavailable."""
    listed = summary.get("input_paths") if summary else None
    if not isinstance(listed, list):
        return [None] * len(cameras), "input photos: summary.json does not list their paths; showing restored views"
    by_name = {Path(p).name: (Path(p) if Path(p).is_absolute() else folder / p) for p in listed if isinstance(p, str)}
    found = [by_name.get(name) for name in cameras.names]
    found = [path if path is not None and path.is_file() else None for path in found]
    missing = sum(path is None for path in found)
    note = f"input photos: {missing} of {len(found)} not found where summary.json says" if missing else None
    return found, note


def _sparse_points(folder: Path) -> SparseCloud | None:
    for path in (folder / "colmap" / "points3D.txt", folder / "sparse" / "0" / "points3D.txt"):
        if path.is_file():
            points = read_colmap_points(path)
            if len(points.xyz):
                return SparseCloud(np.asarray(points.xyz, np.float64), np.asarray(points.rgb, np.uint8))
    return None


def load_viewer_scene(path: Path | str) -> ViewerScene:
    """Read a restore output folder, a `.ply` inside one (its folder is read too), or a bare
    `.ply`; InputError when there is nothing to show."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or folder; {_HINT}")
    if path.is_file():
        if path.suffix.lower() != ".ply":
            raise InputError(f"{path}: not a .ply scene; {_HINT}")
        folder = path.parent
        try:
            summary = _read_summary(folder)
        except InputError as error:  # the .ply was given: it is shown whatever lies beside it
            logger.warning("%s; showing %s alone", error, path)
            summary = None
        beside = summary is not None and Path(str(summary.get("scene", ""))).name == path.name
        if not beside:
            return ViewerScene(path, _read_scene(path), notes=["a bare .ply: no cameras, photos or summary beside it"])
        scene_path = path
    else:
        folder = path
        summary = _read_summary(folder)
        scene_path = _scene_file(folder, summary)
    scene = ViewerScene(scene_path, _read_scene(scene_path), summary=summary, points=_sparse_points(folder))
    if find_camera_source(folder) is None:
        scene.notes.append("no cameras.json beside the scene: no camera frustums")
        return scene
    scene.cameras = read_cameras(folder)
    restored_paths = [_restored_photo(folder, name) for name in scene.cameras.names]
    scene.restored = _thumbnails(restored_paths)
    if any(p is None for p in restored_paths):
        scene.notes.append(f"restored views: {sum(p is None for p in restored_paths)} of {len(restored_paths)} missing in restored/")
    input_paths, note = _input_photos(folder, summary, scene.cameras)
    scene.inputs = _thumbnails(input_paths)
    if note:
        scene.notes.append(note)
    unreadable = sum(p is not None and t is None for p, t in zip([*restored_paths, *input_paths], [*scene.restored, *scene.inputs]))
    if unreadable:
        scene.notes.append(f"photos: {unreadable} could not be read (warned of above); shown without them")
    logger.debug("viewer scene %s: %d Gaussians, %d cameras", scene_path, len(scene.gaussians), len(scene.cameras))
    return scene
