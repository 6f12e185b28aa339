"""Find training scenes on disk: scene folders (images/ + sparse/0 or transforms.json) and the
DL3DV layout (<hash>/transforms.json + images_N/)."""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.colmap import read_colmap_images, read_colmap_model, read_colmap_points
from lumos3d_cli.io.image_files import IMAGE_SUFFIXES, list_images
from lumos3d_cli.io.input_folders import require_folder
from lumos3d_cli.io.transforms_json import read_transforms_json

logger = logging.getLogger(__name__)


@dataclass
class SceneRecord:
    """One scene. image_paths: every image (natural order). cameras[k] belongs to
    image_paths[posed[k]] (None when the scene has no poses). points_xyz [P, 3] sparse points
    (world) and observed[view] = indices of the points seen by image_paths[view] (COLMAP only)."""

    name: str
    image_paths: list[Path]
    cameras: Cameras | None = None
    posed: list[int] = field(default_factory=list)
    points_xyz: np.ndarray | None = None
    observed: dict[int, np.ndarray] = field(default_factory=dict)

    def camera_of(self, view: int) -> int | None:
        """Row of `cameras` for image `view`, or None."""
        try:
            return self.posed.index(view)
        except ValueError:
            return None


def _attach_cameras(record: SceneRecord, cameras: Cameras) -> None:
    by_name = {path.name: index for index, path in enumerate(record.image_paths)}
    rows, views = [], []
    for row, name in enumerate(cameras.names):
        view = by_name.get(Path(name).name)
        if view is not None:
            rows.append(row)
            views.append(view)
    if rows:
        order = np.argsort(views)
        rows = [rows[i] for i in order]
        record.cameras = cameras[rows]
        record.posed = sorted(views)


def _attach_colmap(record: SceneRecord, sparse: Path) -> None:
    # the text form throughout: the points and their tracks below are read from it
    _attach_cameras(record, read_colmap_model(sparse, text=True))
    if not (sparse / "points3D.txt").is_file():
        return
    points = read_colmap_points(sparse / "points3D.txt")
    if len(points.ids) == 0:
        return
    by_name = {path.name: index for index, path in enumerate(record.image_paths)}
    view_of_image = {image.image_id: by_name.get(Path(image.name).name) for image in read_colmap_images(sparse / "images.txt")}
    seen: dict[int, list[int]] = {}
    for point_index, track in enumerate(points.tracks):
        for image_id in np.unique(track):
            view = view_of_image.get(int(image_id))
            if view is not None:
                seen.setdefault(view, []).append(point_index)
    record.points_xyz = points.xyz
    record.observed = {view: np.asarray(indices, dtype=np.int64) for view, indices in seen.items()}


def _without_excluded(root: Path, folders: list[Path], exclude: list[str]) -> list[Path]:
    """`folders` less those named in `exclude`, left out before anything in them is read (a
    damaged scene can be excluded); a name matching no folder is warned of."""
    unknown = sorted(set(exclude) - {folder.name for folder in folders})
    if unknown:  # a misspelt exclusion trains on the scene it meant to leave out; a partial copy has none
        logger.warning("data.exclude: %s: no such training scene under %s (misspelt? nothing is left out for "
                       "it)", ", ".join(unknown), root)
    return [folder for folder in folders if folder.name not in set(exclude)]


def scan_scene_folders(root: Path | str, names: list[str] | None = None, exclude: list[str] = ()) -> list[SceneRecord]:
    """Every `<root>/<scene>/images/` folder (those in `names` when given, never those in
    `exclude`), with poses from `sparse/0` (COLMAP text) or `transforms.json` when present."""
    root = Path(root)
    require_folder(root, "that holds the training scenes (data.root)")
    folders = sorted(p for p in root.iterdir() if (p / "images").is_dir())
    if not folders:
        raise InputError(f"{root}: no scene folders with an images/ subfolder")
    if names:
        wanted = set(names)
        missing = wanted - {p.name for p in folders}
        if missing:
            raise InputError(f"{root}: no scene folder(s) named {', '.join(sorted(missing))}")
        folders = [p for p in folders if p.name in wanted]
    folders = _without_excluded(root, folders, list(exclude))
    records = []
    for folder in folders:
        record = SceneRecord(folder.name, list_images(folder / "images"))
        if (folder / "sparse" / "0" / "images.txt").is_file():
            _attach_colmap(record, folder / "sparse" / "0")
        elif (folder / "transforms.json").is_file():
            _attach_cameras(record, read_transforms_json(folder / "transforms.json"))
        records.append(record)
    return records


def scan_dl3dv(root: Path | str, downsample: int = 4, names: list[str] | None = None,
               exclude: list[str] = ()) -> list[SceneRecord]:
    """DL3DV: `<root>/<hash>/transforms.json` with `images_<downsample>/` holding the frames
    (file names as in transforms.json's file_path); intrinsics are rescaled to those images.
    Scenes in `names` when given, never those in `exclude`."""
    root = Path(root)
    require_folder(root, "that holds the training scenes (data.root)")
    records = []
    folders = [p for p in sorted(root.iterdir()) if (p / "transforms.json").is_file() and (not names or p.name in names)]
    for folder in _without_excluded(root, folders, list(exclude)):
        image_folder = folder / f"images_{downsample}"
        if not image_folder.is_dir():
            logger.warning("%s: no images_%d/ folder; scene skipped", folder, downsample)
            continue
        cameras = read_transforms_json(folder / "transforms.json")
        frames = json.loads((folder / "transforms.json").read_text())["frames"]
        paths = [image_folder / Path(frame["file_path"]).name for frame in frames]
        present = [i for i, path in enumerate(paths) if path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES]
        if not present:
            logger.warning("%s: no frames found in %s; scene skipped", folder, image_folder)
            continue
        cameras = cameras[present]
        width, height = _image_size(paths[present[0]])
        cameras = cameras.rescaled(width, height)
        cameras.names = [paths[i].name for i in present]
        record = SceneRecord(folder.name, [paths[i] for i in present])
        _attach_cameras(record, cameras)
        records.append(record)
    if not records:
        raise InputError(f"{root}: no DL3DV scenes (<hash>/transforms.json with images_{downsample}/)")
    return records


def _image_size(path: Path) -> tuple[int, int]:
    from lumos3d_cli.io.images import probe_image

    header = probe_image(path)
    return header.width, header.height
