"""Save images: 8/16-bit sRGB PNG or JPEG through OpenCV, linear EXR through OpenImageIO."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import OpenImageIO as oiio

from lumos3d_cli.checks import require_finite
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import atomic_path, write_bytes_atomic

_MAX_CODE = {8: 255, 16: 65535}
DEFAULT_JPEG_QUALITY = 95
JPEG_MAX_SIDE = 65500  # the JPEG format's 16-bit sizes, less libjpeg's margin
PNG_MAX_SIDE = 1_000_000  # libpng's default limit on either side when OpenCV writes
_DTYPE = {8: np.uint8, 16: np.uint16}


def quantize(srgb: np.ndarray, bit_depth: int) -> np.ndarray:
    """[H, W, 3] float in [0, 1] -> integer codes, rounded to nearest."""
    scale = _MAX_CODE[bit_depth]
    return np.round(np.clip(srgb, 0.0, 1.0) * scale).astype(_DTYPE[bit_depth])


def write_image(path: Path | str, srgb: np.ndarray, bit_depth: int = 8, jpeg_quality: int = DEFAULT_JPEG_QUALITY) -> None:
    """Write [H, W, 3] sRGB float pixels to PNG (8/16 bit) or JPEG (8 bit), atomically."""
    path = Path(path)
    require_finite(f"image for {path}", srgb)
    suffix = path.suffix.lower()
    if bit_depth not in _MAX_CODE:
        raise InputError(f"bit depth {bit_depth}: use 8 or 16")
    if suffix in (".jpg", ".jpeg") and bit_depth != 8:
        raise InputError(f"{path}: JPEG holds 8 bits only; use .png for 16-bit output")
    if suffix not in (".png", ".jpg", ".jpeg"):
        raise InputError(f"{path}: cannot write '{path.suffix}' here; use .png, .jpg or .exr")
    if suffix != ".png" and max(srgb.shape[:2]) > JPEG_MAX_SIDE:
        raise InputError(f"{path}: {srgb.shape[1]}x{srgb.shape[0]} pixels; JPEG holds at most {JPEG_MAX_SIDE} a side: "
                         "use .png")
    if max(srgb.shape[:2]) > PNG_MAX_SIDE:
        raise InputError(f"{path}: {srgb.shape[1]}x{srgb.shape[0]} pixels; a PNG written here holds at most "
                         f"{PNG_MAX_SIDE:,} a side: crop or downscale the image")
    codes = np.ascontiguousarray(quantize(srgb, bit_depth)[..., ::-1])
    params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if suffix != ".png" else []
    ok, encoded = cv2.imencode(suffix, codes, params)
    if not ok:
        raise OSError(f"{path}: OpenCV could not encode the image")
    write_bytes_atomic(path, encoded.tobytes())


def write_exr(path: Path | str, linear: np.ndarray, half: bool = True) -> None:
    """Write [H, W, 3] linear float pixels to OpenEXR (half or full float), atomically."""
    path = Path(path)
    require_finite(f"image for {path}", linear)
    height, width = linear.shape[:2]
    spec = oiio.ImageSpec(width, height, 3, oiio.HALF if half else oiio.FLOAT)
    spec.channelnames = ("R", "G", "B")
    spec.attribute("compression", "zip")
    with atomic_path(path) as temporary:
        out = oiio.ImageOutput.create(str(temporary))
        if out is None or not out.open(str(temporary), spec):
            raise OSError(f"{path}: cannot open for writing ({oiio.geterror().strip()})")
        try:
            if not out.write_image(np.ascontiguousarray(linear, dtype=np.float32)):
                raise OSError(f"{path}: cannot write EXR ({out.geterror().strip()})")
        finally:
            out.close()
