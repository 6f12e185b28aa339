"""nerfstudio / instant-ngp `transforms.json` (also LOM's `transforms_{train,val,test}.json`).

camera->world 4x4 per frame with OpenGL axes; intrinsics fl_x, fl_y, cx, cy, w, h at the top
level or per frame (per-frame values win); `camera_angle_x` alone is accepted as in NeRF's
synthetic scenes. Lens distortion (k1, k2, p1, p2 ...) is ignored with a warning.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import write_bytes_atomic
from lumos3d_cli.io.cameras import Cameras, make_intrinsics, opencv_to_opengl, opengl_to_opencv
from lumos3d_cli.io.image_files import IMAGE_SUFFIXES

logger = logging.getLogger(__name__)

_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
# nerfstudio's camera_model values of perspective lenses (OPENCV's distortion is ignored with a warning)
_PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "OPENCV", "SIMPLE_RADIAL", "RADIAL", "FULL_OPENCV", "PERSPECTIVE")


def _image_size(path: Path, index: int, frame: dict, merged: dict) -> tuple[int, int]:
    if "w" in merged and "h" in merged:
        width, height = _number(path, index, merged, "w"), _number(path, index, merged, "h")
        if not (math.isfinite(width) and math.isfinite(height)):
            raise InputError(f"{path}: frame {index} has the image size {width}x{height}; correct the file")
        return round(width), round(height)
    from lumos3d_cli.io.images import probe_image  # only needed for files without w/h

    image_path = path.parent / str(frame.get("file_path", ""))
    if image_path.is_file():
        header = probe_image(image_path)
        return header.width, header.height
    if image_path.parent.is_dir():  # the file named by its stem, with any suffix and in any case
        stem = image_path.stem.casefold()
        for candidate in sorted(image_path.parent.iterdir()):
            if candidate.stem.casefold() == stem and candidate.suffix.lower() in IMAGE_SUFFIXES and candidate.is_file():
                header = probe_image(candidate)
                return header.width, header.height
    raise InputError(f"{path}: frame {frame.get('file_path')!r} has no 'w'/'h' and its image was not found")


def _number(path: Path, index: int, merged: dict, key: str) -> float:
    """merged[key] as a float; InputError naming the file, the frame and the key otherwise."""
    try:
        if isinstance(merged[key], bool):  # float(True) is 1.0: "w": true was a frame 1 pixel wide
            raise TypeError
        return float(merged[key])
    except (TypeError, ValueError):
        raise InputError(f"{path}: frame {index} has {key} {merged[key]!r}, which is not a number; correct the file") from None


def _focal_from_angle(path: Path, index: int, merged: dict, key: str, size: int) -> float:
    """The focal length in pixels of a field of view merged[key] (radians, across `size` pixels);
    InputError unless the angle lies strictly between 0 and pi (180 degrees)."""
    angle = _number(path, index, merged, key)
    if not 0.0 < angle < math.pi:
        raise InputError(f"{path}: frame {index} has {key} {angle}, but a field of view lies between 0 and pi "
                         "radians (180 degrees) exclusive; correct the file")
    return 0.5 * size / math.tan(0.5 * angle)


def read_transforms_json(path: Path | str, warn_on_distortion: bool = True) -> Cameras:
    """Read all frames in file order. `warn_on_distortion=False` for callers that use only the
    poses, which the lens distortion does not affect."""
    path = Path(path)
    try:
        document = json.loads(path.read_text(encoding="utf-8"))  # JSON is UTF-8, whatever the locale
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"{path}: cannot read ({error})") from error
    except json.JSONDecodeError as error:
        raise InputError(f"{path}: invalid JSON ({error.msg} at line {error.lineno})") from error
    frames = document.get("frames") if isinstance(document, dict) else None
    if not isinstance(frames, list):
        raise InputError(f"{path}: no 'frames' list; not a transforms.json camera file")
    if not frames:
        raise InputError(f"{path}: its 'frames' list is empty; the file holds no camera")
    model = document.get("camera_model", "OPENCV")
    if str(model).upper() not in _PINHOLE_MODELS:  # a fisheye or panorama is no pinhole camera, distortion or not
        raise InputError(f"{path}: camera_model {model!r} is not a perspective camera; undistort the images to "
                         "pinhole ones first (e.g. nerfstudio's or COLMAP's undistorter)")
    camera_to_world, fx, fy, cx, cy, sizes, names = [], [], [], [], [], [], []
    distorted = False
    for index, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise InputError(f"{path}: frame {index} is {type(frame).__name__} {str(frame)[:40]}, not an object with a "
                             "'transform_matrix'; correct the file")
        merged = {**document, **frame}
        if "camera_angle_x" in frame:  # a frame's own field of view wins over a focal length of the top level
            merged = {key: value for key, value in merged.items() if key not in ("fl_x", "fl_y") or key in frame}
        try:
            matrix = torch.tensor(frame["transform_matrix"], dtype=torch.float64)
        except (KeyError, TypeError, ValueError) as error:
            raise InputError(f"{path}: frame {index} has no valid 'transform_matrix'") from error
        if matrix.shape == (3, 4):
            matrix = torch.cat([matrix, torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=torch.float64)])
        if matrix.shape != (4, 4):
            raise InputError(f"{path}: frame {index} 'transform_matrix' is {tuple(matrix.shape)}, expected 4x4")
        if not torch.allclose(matrix[3], torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64), atol=1e-6):
            raise InputError(f"{path}: frame {index} 'transform_matrix' has the last row {matrix[3].tolist()}, but a "
                             "camera pose's is [0, 0, 0, 1]; correct the file")
        width, height = _image_size(path, index, frame, merged)
        if "fl_x" in merged:
            focal_x = _number(path, index, merged, "fl_x")
            focal_y = _number(path, index, merged, "fl_y") if "fl_y" in merged else focal_x
        elif "camera_angle_x" in merged:
            focal_x = _focal_from_angle(path, index, merged, "camera_angle_x", width)
            focal_y = _focal_from_angle(path, index, merged, "camera_angle_y", height) if "camera_angle_y" in merged else focal_x
        else:
            raise InputError(f"{path}: frame {index} has no focal length ('fl_x' or 'camera_angle_x')")
        distorted |= any(abs(_number(path, index, merged, key)) > 0 for key in _DISTORTION_KEYS if merged.get(key) is not None)
        camera_to_world.append(opengl_to_opencv(matrix))
        fx.append(focal_x)
        fy.append(focal_y)
        cx.append(_number(path, index, merged, "cx") if "cx" in merged else width / 2)
        cy.append(_number(path, index, merged, "cy") if "cy" in merged else height / 2)
        sizes.append((width, height))
        names.append(str(frame.get("file_path", "")))
    if distorted and warn_on_distortion:
        logger.warning("%s: lens distortion coefficients are ignored (pinhole model)", path)
    cameras = Cameras.from_camera_to_world(torch.stack(camera_to_world), make_intrinsics(fx, fy, cx, cy), sizes, names)
    cameras.require_valid(str(path))
    return cameras


def cameras_to_transforms_document(cameras: Cameras) -> dict:
    """The transforms.json document; shared intrinsics go to the top level."""
    intrinsics = cameras.intrinsics.double()
    params = torch.stack(
        [intrinsics[:, 0, 0], intrinsics[:, 1, 1], intrinsics[:, 0, 2], intrinsics[:, 1, 2]], dim=1
    )
    shared = bool((params == params[:1]).all()) and len(set(cameras.sizes)) == 1
    document: dict = {"camera_model": "PINHOLE"}

    def intrinsic_fields(i: int) -> dict:
        fl_x, fl_y, c_x, c_y = (float(v) for v in params[i])
        return {"fl_x": fl_x, "fl_y": fl_y, "cx": c_x, "cy": c_y, "w": cameras.sizes[i][0], "h": cameras.sizes[i][1]}

    if shared:
        document.update(intrinsic_fields(0))
    camera_to_world = opencv_to_opengl(cameras.camera_to_world().double())
    frames = []
    for i in range(len(cameras)):
        frame = {"file_path": cameras.names[i], "transform_matrix": camera_to_world[i].tolist()}
        if not shared:
            frame.update(intrinsic_fields(i))
        frames.append(frame)
    document["frames"] = frames
    return document


def write_transforms_json(path: Path | str, cameras: Cameras) -> None:
    """Write atomically (camera->world, OpenGL axes, as nerfstudio expects)."""
    cameras.require_valid("cameras to save", remedy="nothing was written")
    write_bytes_atomic(path, (json.dumps(cameras_to_transforms_document(cameras), indent=2) + "\n").encode())
