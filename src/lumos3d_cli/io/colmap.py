"""COLMAP sparse models in text form: cameras.txt, images.txt, points3D.txt.

COLMAP stores world->camera rotations as wxyz quaternions and uses the same pixel convention
as `Cameras` (origin at the top-left pixel corner). Only the pinhole part of each camera model
is used; distortion parameters are ignored with a warning.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import write_bytes_atomic
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.image_files import natural_sort_key
from lumos3d_cli.rotations import matrix_to_quaternion, quaternion_to_matrix

logger = logging.getLogger(__name__)

# Camera models whose parameters start with one shared focal length (f, cx, cy, ...).
_SINGLE_FOCAL = {"SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"}
# Camera models whose parameters start with (fx, fy, cx, cy, ...).
_DUAL_FOCAL = {"PINHOLE", "OPENCV", "OPENCV_FISHEYE", "FULL_OPENCV", "FOV", "THIN_PRISM_FISHEYE", "RAD_TAN_THIN_PRISM_FISHEYE"}
_PINHOLE = {"SIMPLE_PINHOLE", "PINHOLE"}


@dataclass(frozen=True)
class ColmapCamera:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    model: str


@dataclass(frozen=True)
class ColmapPoints:
    """Sparse points: xyz [P, 3] float64, rgb [P, 3] uint8, error [P], tracks: image ids per point."""

    ids: np.ndarray
    xyz: np.ndarray
    rgb: np.ndarray
    error: np.ndarray
    tracks: list[np.ndarray]


def _data_lines(path: Path) -> list[str]:
    try:
        text = path.read_text()
    except OSError as error:
        raise InputError(f"{path}: cannot read ({error.strerror})") from error
    return [line for line in text.splitlines() if not line.startswith("#")]


def read_colmap_cameras(path: Path) -> dict[int, ColmapCamera]:
    cameras = {}
    for number, line in enumerate(_data_lines(path), 1):
        words = line.split()
        if not words:
            continue
        try:
            camera_id, model, width, height = int(words[0]), words[1], int(words[2]), int(words[3])
            params = [float(v) for v in words[4:]]
            if model in _SINGLE_FOCAL:
                fx = fy = params[0]
                cx, cy = params[1], params[2]
            elif model in _DUAL_FOCAL:
                fx, fy, cx, cy = params[:4]
            else:
                raise InputError(f"{path}: camera model {model} is not supported; undistort the images with COLMAP first")
        except (IndexError, ValueError) as error:
            raise InputError(f"{path}: cannot parse camera line {number}: {line!r}") from error
        if model not in _PINHOLE:
            logger.warning("%s: camera %d (%s): distortion parameters are ignored", path, camera_id, model)
        cameras[camera_id] = ColmapCamera(width, height, fx, fy, cx, cy, model)
    return cameras


@dataclass(frozen=True)
class ColmapImage:
    image_id: int
    name: str
    qvec: tuple[float, float, float, float]
    tvec: tuple[float, float, float]
    camera_id: int


def read_colmap_images(path: Path) -> list[ColmapImage]:
    """Image lines of images.txt (each is followed by a POINTS2D line, possibly empty)."""
    lines = _data_lines(path)
    images = []
    index = 0
    while index < len(lines):
        words = lines[index].split()
        if len(words) < 10:
            index += 1
            continue
        try:
            images.append(ColmapImage(
                int(words[0]), " ".join(words[9:]), tuple(float(v) for v in words[1:5]),
                tuple(float(v) for v in words[5:8]), int(words[8]),
            ))
        except ValueError as error:
            raise InputError(f"{path}: cannot parse image line {lines[index]!r}") from error
        index += 2
    return images


def read_colmap_model(folder: Path | str) -> Cameras:
    """Read cameras.txt and images.txt from a sparse model folder; views sorted by image name."""
    folder = Path(folder)
    for name in ("cameras.txt", "images.txt"):
        if not (folder / name).is_file():
            raise InputError(f"{folder}: no {name}; expected a COLMAP text model (use `colmap model_converter` for .bin)")
    cameras = read_colmap_cameras(folder / "cameras.txt")
    views = sorted(read_colmap_images(folder / "images.txt"), key=lambda view: natural_sort_key(view.name))
    if not views:
        raise InputError(f"{folder / 'images.txt'}: no registered images")
    for view in views:
        if view.camera_id not in cameras:
            raise InputError(f"{folder / 'images.txt'}: image {view.name} refers to unknown camera {view.camera_id}")
    rotation = quaternion_to_matrix(torch.tensor([v.qvec for v in views], dtype=torch.float64))
    translation = torch.tensor([v.tvec for v in views], dtype=torch.float64)
    extrinsics = torch.cat([rotation, translation[:, :, None]], dim=2)
    intrinsics = torch.zeros(len(views), 3, 3, dtype=torch.float64)
    sizes = []
    for i, view in enumerate(views):
        cam = cameras[view.camera_id]
        intrinsics[i] = torch.tensor([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]], dtype=torch.float64)
        sizes.append((cam.width, cam.height))
    result = Cameras(extrinsics, intrinsics, sizes, [v.name for v in views])
    result.require_valid(str(folder))
    return result


def read_colmap_points(path: Path | str) -> ColmapPoints:
    """Read points3D.txt (POINT3D_ID X Y Z R G B ERROR TRACK[] as IMAGE_ID POINT2D_IDX pairs)."""
    path = Path(path)
    ids, xyz, rgb, error, tracks = [], [], [], [], []
    for line in _data_lines(path):
        words = line.split()
        if not words:
            continue
        try:
            ids.append(int(words[0]))
            xyz.append([float(v) for v in words[1:4]])
            rgb.append([int(v) for v in words[4:7]])
            error.append(float(words[7]))
            tracks.append(np.asarray(words[8::2], dtype=np.int64))
        except (IndexError, ValueError) as exc:
            raise InputError(f"{path}: cannot parse point line {line[:80]!r}") from exc
    return ColmapPoints(
        np.asarray(ids, dtype=np.int64), np.asarray(xyz, dtype=np.float64).reshape(-1, 3),
        np.asarray(rgb, dtype=np.uint8).reshape(-1, 3), np.asarray(error, dtype=np.float64), tracks,
    )


def write_colmap_model(folder: Path | str, cameras: Cameras) -> None:
    """Write cameras.txt (PINHOLE, one per view), images.txt and an empty points3D.txt."""
    folder = Path(folder)
    cameras.require_valid("cameras to save")
    k = cameras.intrinsics.double()
    camera_lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
                    f"# Number of cameras: {len(cameras)}"]
    image_lines = ["# Image list with two lines of data per image:",
                   "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)",
                   f"# Number of images: {len(cameras)}, mean observations per image: 0"]
    quats = matrix_to_quaternion(cameras.extrinsics[:, :, :3].double())
    for i in range(len(cameras)):
        width, height = cameras.sizes[i]
        params = " ".join(repr(float(v)) for v in (k[i, 0, 0], k[i, 1, 1], k[i, 0, 2], k[i, 1, 2]))
        camera_lines.append(f"{i + 1} PINHOLE {width} {height} {params}")
        q = " ".join(repr(float(v)) for v in quats[i])
        t = " ".join(repr(float(v)) for v in cameras.extrinsics[i, :, 3].double())
        name = cameras.names[i] or f"{i:05d}.png"
        image_lines += [f"{i + 1} {q} {t} {i + 1} {name}", ""]
    points_lines = ["# 3D point list with one line of data per point:",
                    "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
                    "# Number of points: 0, mean track length: 0"]
    write_bytes_atomic(folder / "cameras.txt", ("\n".join(camera_lines) + "\n").encode())
    write_bytes_atomic(folder / "images.txt", ("\n".join(image_lines) + "\n").encode())
    write_bytes_atomic(folder / "points3D.txt", ("\n".join(points_lines) + "\n").encode())
