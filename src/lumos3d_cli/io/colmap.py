"""COLMAP sparse models: cameras, images and points3D, read in text or binary form (binary
through pycolmap), written in both: the text form for people and tools that read text, the
binary form (which COLMAP and pycolmap prefer when both are there) because COLMAP's text reader
cuts an image name at its first space.

COLMAP stores world->camera rotations as wxyz quaternions and uses the same pixel convention
as `Cameras` (origin at the top-left pixel corner). Only the pinhole part of each camera model
is used; distortion parameters are ignored with a warning.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pycolmap
import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.errors import InputError, listed
from lumos3d_cli.io.atomic import write_bytes_atomic
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.image_files import natural_sort_key
from lumos3d_cli.io.sparse_points import SparsePoints
from lumos3d_cli.rotations import matrix_to_quaternion, quaternion_to_matrix

logger = logging.getLogger(__name__)

# Perspective camera models whose parameters start with one shared focal length (f, cx, cy, ...).
_SINGLE_FOCAL = {"SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"}
# Perspective camera models whose parameters start with (fx, fy, cx, cy, ...).
_DUAL_FOCAL = {"PINHOLE", "OPENCV", "FULL_OPENCV"}
_PINHOLE = {"SIMPLE_PINHOLE", "PINHOLE"}
# The others (the fisheye models, FOV, the division models) project otherwise even with every
# coefficient zero (an equidistant fisheye puts a point at f * angle, not f * tan(angle)): refused.


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


def _text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")  # COLMAP writes UTF-8 names, whatever the locale
    except OSError as error:
        raise InputError(f"{path}: cannot read ({error.strerror})") from error
    except UnicodeDecodeError as error:
        raise InputError(f"{path}: not UTF-8 text ({error.reason} at byte {error.start}); write the model as COLMAP "
                         "does, or give its binary form") from error


def _data_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if not line.startswith("#")]


def read_colmap_cameras(path: Path) -> dict[int, ColmapCamera]:
    cameras = {}
    for number, line in enumerate(_data_lines(_text(path)), 1):
        words = line.split()
        if not words:
            continue
        try:
            camera_id, model, width, height = int(words[0]), words[1], int(words[2]), int(words[3])
            params = [float(v) for v in words[4:]]
            cameras[camera_id] = _pinhole_camera(path, camera_id, model, width, height, params)
        except (IndexError, ValueError) as error:
            raise InputError(f"{path}: cannot parse camera line {number}: {line!r}") from error
    return cameras


def _pinhole_camera(path: Path, camera_id: int, model: str, width: int, height: int, params: list[float]) -> ColmapCamera:
    """The pinhole part of a COLMAP camera (IndexError for too few parameters)."""
    if model in _SINGLE_FOCAL:
        fx = fy = params[0]
        cx, cy = params[1], params[2]
    elif model in _DUAL_FOCAL:
        fx, fy, cx, cy = params[:4]
    else:
        raise InputError(f"{path}: camera model {model} is no perspective (pinhole) camera; undistort the images with "
                         "COLMAP first (colmap image_undistorter)")
    return ColmapCamera(width, height, fx, fy, cx, cy, model)


@dataclass(frozen=True)
class ColmapImage:
    image_id: int
    name: str
    qvec: tuple[float, float, float, float]
    tvec: tuple[float, float, float]
    camera_id: int


def _is_image_line(line: str) -> bool:
    """Whether `line` reads as an images.txt image line (IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID
    NAME) rather than a POINTS2D line (numbers only, three per observation)."""
    words = line.split()
    if len(words) < 10:
        return False
    try:
        int(words[0]), [float(v) for v in words[1:8]], int(words[8])
    except ValueError:
        return False
    try:
        [float(v) for v in words]
    except ValueError:
        return True  # a name that is no number
    return len(words) % 3 != 0


def read_colmap_images(path: Path) -> list[ColmapImage]:
    """Image lines of images.txt, each followed by its POINTS2D line (possibly empty). An image
    line followed by another image line is refused: a file whose POINTS2D lines were left out
    would otherwise lose every second image."""
    lines = _data_lines(_text(path))
    images = []
    index = 0
    while index < len(lines):
        # The name is the rest of the line after nine fields, spaces inside it kept as written
        # (trailing ones dropped, as COLMAP does).
        words = lines[index].split(maxsplit=9)
        if len(words) < 10:
            index += 1
            continue
        try:
            images.append(ColmapImage(
                int(words[0]), words[9].rstrip(), tuple(float(v) for v in words[1:5]),
                tuple(float(v) for v in words[5:8]), int(words[8]),
            ))
        except ValueError as error:
            raise InputError(f"{path}: cannot parse image line {lines[index]!r}") from error
        if index + 1 < len(lines) and _is_image_line(lines[index + 1]):
            raise InputError(f"{path}: image {words[9].rstrip()!r} is followed by another image line, not its POINTS2D "
                             "line; every image line must be followed by one (an empty line if it has none)")
        index += 2
    return images


def is_colmap_model(folder: Path) -> bool:
    """A folder with cameras and images of a COLMAP model, in text or binary form."""
    return all((folder / f"{name}.txt").is_file() for name in ("cameras", "images")) or all(
        (folder / f"{name}.bin").is_file() for name in ("cameras", "images"))


def _read_reconstruction(folder: Path) -> pycolmap.Reconstruction:
    """A text or binary model through pycolmap (InputError when COLMAP cannot read it)."""
    binary = [(folder / f"{name}.bin").is_file() for name in ("cameras", "images", "points3D")]
    if any(binary) and not all(binary) and not (folder / "points3D.txt").is_file():
        raise InputError(f"{folder}: a binary COLMAP model needs cameras.bin, images.bin and points3D.bin; "
                         f"{', '.join(n + '.bin' for n, ok in zip(('cameras', 'images', 'points3D'), binary) if not ok)} "
                         "missing: copy the whole model")
    try:
        return pycolmap.Reconstruction(folder)
    except Exception as error:  # pycolmap raises plain RuntimeError/ValueError for unreadable files
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise InputError(f"{folder}: not a readable COLMAP model, damaged or truncated ({reason}); write it again with "
                         "COLMAP") from error


def _read_binary_views(folder: Path) -> tuple[dict[int, ColmapCamera], list[ColmapImage]]:
    reconstruction = _read_reconstruction(folder)
    cameras = {}
    for camera_id, camera in reconstruction.cameras.items():
        try:
            cameras[camera_id] = _pinhole_camera(folder / "cameras.bin", camera_id, camera.model_name,
                                                 camera.width, camera.height, [float(v) for v in camera.params])
        except IndexError as error:
            raise InputError(f"{folder / 'cameras.bin'}: camera {camera_id} has too few parameters") from error
    views = []
    for image_id, image in reconstruction.images.items():
        if not image.has_pose:
            continue
        pose = image.cam_from_world()
        x, y, z, w = (float(v) for v in pose.rotation.quat)  # Eigen's order: xyzw
        views.append(ColmapImage(image_id, image.name, (w, x, y, z), tuple(float(v) for v in pose.translation), image.camera_id))
    return cameras, views


def read_colmap_model(folder: Path | str, warn_on_distortion: bool = True, text: bool = False) -> Cameras:
    """Read the cameras of a sparse model folder (cameras.bin + images.bin + points3D.bin first, as
    COLMAP does, else cameras.txt + images.txt; `text`: the text form, for a caller that reads its
    points3D.txt too); views sorted by image name. Distortion parameters are ignored (pinhole),
    with a warning unless `warn_on_distortion` is False (a caller that read the model once already)."""
    folder = Path(folder)
    if not is_colmap_model(folder):
        raise InputError(f"{folder}: no cameras.txt + images.txt (or cameras.bin + images.bin); expected a COLMAP model folder")
    has_text = all((folder / f"{name}.txt").is_file() for name in ("cameras", "images"))
    binary = all((folder / f"{name}.bin").is_file() for name in ("cameras", "images", "points3D")) and not (text and has_text)
    if binary or not has_text:
        cameras, views = _read_binary_views(folder)  # COLMAP and pycolmap read the binary form first
    else:
        cameras = read_colmap_cameras(folder / "cameras.txt")
        views = read_colmap_images(folder / "images.txt")
    distorted = [f"{camera_id} ({camera.model})" for camera_id, camera in sorted(cameras.items()) if camera.model not in _PINHOLE]
    if distorted and warn_on_distortion:  # one line for the model, not one per camera
        logger.warning("%s: the distortion parameters of camera(s) %s are ignored (pinhole model)", folder,
                       listed(distorted, 4))
    views = sorted(views, key=lambda view: natural_sort_key(view.name))
    if not views:
        raise InputError(f"{folder}: the model has no registered images")
    for view in views:
        if view.camera_id not in cameras:
            raise InputError(f"{folder}: image {view.name} refers to unknown camera {view.camera_id}")
        length = math.sqrt(sum(q * q for q in view.qvec))
        if not math.isfinite(length) or length < 1e-9 or not all(math.isfinite(t) for t in view.tvec):
            raise InputError(f"{folder}: image {view.name} has the rotation quaternion {list(view.qvec)} and translation "
                             f"{list(view.tvec)}, which are not a pose (zero-length or non-finite); correct the model")
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
    result.require_valid(str(folder), remedy="correct the model")
    return result


def read_colmap_points(path: Path | str) -> ColmapPoints:
    """Read points3D.txt (POINT3D_ID X Y Z R G B ERROR TRACK[] as IMAGE_ID POINT2D_IDX pairs)."""
    path = Path(path)
    ids, xyz, rgb, error, tracks = [], [], [], [], []
    for line in _data_lines(_text(path)):
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
        if not all(math.isfinite(v) for v in xyz[-1]):
            raise InputError(f"{path}: point {ids[-1]} lies at {' '.join(words[1:4])}, which is not a position; "
                             "correct or remove its line")
    return ColmapPoints(
        np.asarray(ids, dtype=np.int64), np.asarray(xyz, dtype=np.float64).reshape(-1, 3),
        np.asarray(rgb, dtype=np.uint8).reshape(-1, 3), np.asarray(error, dtype=np.float64), tracks,
    )


def sparse_points_of(reconstruction: pycolmap.Reconstruction, view_of_image: dict[int, int]) -> SparsePoints:
    """The points of a pycolmap reconstruction with the observations of the images in
    `view_of_image` (COLMAP image id -> view index); pixels and errors in the model's own image
    pixels. Observations of other images are dropped."""
    point_ids = sorted(reconstruction.points3D.keys())
    position = {point_id: index for index, point_id in enumerate(point_ids)}
    points = [reconstruction.points3D[point_id] for point_id in point_ids]
    view, point, pixel = [], [], []
    for image_id, index in view_of_image.items():
        for observation in reconstruction.images[image_id].get_observation_points2D():
            view.append(index)
            point.append(position[observation.point3D_id])
            pixel.append(observation.xy)
    return SparsePoints(
        torch.tensor(np.array([p.xyz for p in points], dtype=np.float64).reshape(-1, 3)),
        torch.tensor(np.array([p.color for p in points], dtype=np.uint8).reshape(-1, 3)),
        torch.tensor([p.error for p in points], dtype=torch.float64),
        torch.tensor(view, dtype=torch.int64), torch.tensor(point, dtype=torch.int64),
        torch.tensor(np.array(pixel, dtype=np.float64).reshape(-1, 2)),
    )


def _observation_lines(cameras: Cameras, points: SparsePoints | None) -> tuple[list[str], list[str]]:
    """The POINTS2D line of each image and the points3D.txt data lines (tracks refer to the
    position of each observation in its image's POINTS2D line)."""
    if points is None:
        return [""] * len(cameras), []
    if len(points.view) and (int(points.view.min()) < 0 or int(points.view.max()) >= len(cameras)):
        raise ValueError(f"sparse points observe view {int(points.view.max())} of {len(cameras)} cameras")
    require_finite("sparse points", points.xyz)
    image_words: list[list[str]] = [[] for _ in range(len(cameras))]
    tracks: list[list[str]] = [[] for _ in range(len(points))]
    for view, point, (u, v) in zip(points.view.tolist(), points.point.tolist(), points.pixel.tolist()):
        tracks[point].append(f"{view + 1} {len(image_words[view])}")
        image_words[view].append(f"{u!r} {v!r} {point + 1}")
    point_lines = []
    for index in range(len(points)):
        x, y, z = points.xyz[index].tolist()
        r, g, b = points.rgb[index].tolist()
        point_lines.append(f"{index + 1} {x!r} {y!r} {z!r} {r} {g} {b} {float(points.error[index])!r} {' '.join(tracks[index])}".rstrip())
    return [" ".join(words) for words in image_words], point_lines


def write_colmap_model(folder: Path | str, cameras: Cameras, points: SparsePoints | None = None) -> None:
    """Write cameras.txt (PINHOLE, one per view), images.txt and points3D.txt, and the same model
    in binary (cameras.bin, images.bin, points3D.bin, and COLMAP's rigs.bin and frames.bin);
    `points` (their `view` indexing `cameras`) fill points3D with tracks and images with 2D
    points, so the model opens in COLMAP as a reconstruction; without them points3D is empty."""
    folder = Path(folder)
    cameras.require_valid("cameras to save", remedy="nothing was written")
    observations, point_lines = _observation_lines(cameras, points)
    k = cameras.intrinsics.double()
    camera_lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
                    f"# Number of cameras: {len(cameras)}"]
    mean_observations = len(points.view) / len(cameras) if points is not None and len(cameras) else 0
    image_lines = ["# Image list with two lines of data per image:",
                   "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)",
                   f"# Number of images: {len(cameras)}, mean observations per image: {mean_observations:g}"]
    quats = matrix_to_quaternion(cameras.extrinsics[:, :, :3].double())
    for i in range(len(cameras)):
        width, height = cameras.sizes[i]
        params = " ".join(repr(float(v)) for v in (k[i, 0, 0], k[i, 1, 1], k[i, 0, 2], k[i, 1, 2]))
        camera_lines.append(f"{i + 1} PINHOLE {width} {height} {params}")
        q = " ".join(repr(float(v)) for v in quats[i])
        t = " ".join(repr(float(v)) for v in cameras.extrinsics[i, :, 3].double())
        name = cameras.names[i] or f"{i:05d}.png"
        image_lines += [f"{i + 1} {q} {t} {i + 1} {name}", observations[i]]
    track_length = len(points.view) / len(points) if points is not None and len(points) else 0
    points_lines = ["# 3D point list with one line of data per point:",
                    "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
                    f"# Number of points: {len(point_lines)}, mean track length: {track_length:g}", *point_lines]
    write_bytes_atomic(folder / "cameras.txt", ("\n".join(camera_lines) + "\n").encode())
    write_bytes_atomic(folder / "images.txt", ("\n".join(image_lines) + "\n").encode())
    write_bytes_atomic(folder / "points3D.txt", ("\n".join(points_lines) + "\n").encode())
    # The binary copy, by pycolmap from the text just written; its text reader cut each name at
    # the first space, so the names are set again from ours (image i + 1 is view i).
    reconstruction = pycolmap.Reconstruction(str(folder))
    for image_id, image in reconstruction.images.items():
        image.name = cameras.names[image_id - 1] or f"{image_id - 1:05d}.png"
    reconstruction.write_binary(str(folder))
