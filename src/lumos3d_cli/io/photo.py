"""JPEG, PNG, TIFF, WebP and BMP through OpenCV (EXIF orientation applied, alpha dropped with a
warning where it hides pixels)."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import OpenImageIO as oiio

from lumos3d_cli.checks import count_non_finite
from lumos3d_cli.errors import InputError, NonFiniteError
from lumos3d_cli.io.image_types import DecodedImage, ImageHeader

# IMREAD_COLOR applies EXIF orientation, turns grayscale into 3 channels and drops alpha;
# IMREAD_ANYDEPTH keeps 16-bit and float samples.
_READ_FLAGS = cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH
_TRANSPOSING_ORIENTATIONS = {5, 6, 7, 8}
_ALPHA_SUFFIXES = {".png", ".tif", ".tiff", ".webp"}  # the photo formats that can carry alpha

logger = logging.getLogger(__name__)


def read_file_bytes(path: Path) -> np.ndarray:
    """The file's bytes; InputError for a missing, unreadable or empty file."""
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as error:
        raise InputError(f"{path}: cannot read file ({error.strerror}); check the path and permissions") from error
    if data.size == 0:
        raise InputError(f"{path}: file is empty (0 bytes); re-export the image or remove it")
    return data


def require_finite_samples(path: Path, rgb: np.ndarray) -> None:
    """NonFiniteError naming the file when decoded float samples hold NaN or Inf (float TIFF,
    EXR, HDR): they would reach the network and every output."""
    bad = count_non_finite(rgb)
    if bad:
        raise NonFiniteError(f"{path}: {bad} of {rgb.size} samples are NaN or Inf; clamp or repair the file before use")


def _warn_of_transparency(path: Path, data: np.ndarray) -> None:
    """A warning when the photo has an alpha channel that hides some pixels: alpha is dropped, so
    whatever colour lies under them is restored as part of the photo."""
    if path.suffix.lower() not in _ALPHA_SUFFIXES:
        return
    source = oiio.ImageInput.open(str(path))  # the header only: most photos carry no alpha
    if source is None:
        return  # the decoder has read the file; a header this library cannot read says nothing of alpha
    try:
        has_alpha = source.spec().alpha_channel >= 0 or source.spec().nchannels in (2, 4)
    finally:
        source.close()
    if not has_alpha:
        return
    pixels = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if pixels is None or pixels.ndim != 3 or pixels.shape[2] not in (2, 4):
        return
    alpha = pixels[..., -1]
    hidden = float(np.mean(alpha < np.iinfo(alpha.dtype).max if alpha.dtype.kind == "u" else alpha < 1))
    if hidden > 0:
        logger.warning("%s: %.1f %% of its pixels are transparent; alpha is ignored, so the colour under them is "
                       "restored too: flatten the image onto a background first to choose that colour", path, 100 * hidden)


def read_photo(path: Path) -> DecodedImage:
    """Decode a photo to RGB float32: [0, 1] sRGB for 8/16-bit files, linear for float TIFFs."""
    data = read_file_bytes(path)
    bgr = cv2.imdecode(data, _READ_FLAGS)
    if bgr is None:
        raise InputError(
            f"{path}: cannot decode as {path.suffix.lstrip('.').upper()} (corrupt, truncated or not an image); "
            "replace or remove the file"
        )
    _warn_of_transparency(path, data)
    rgb = np.ascontiguousarray(bgr[..., ::-1])
    if rgb.dtype == np.uint8:
        return DecodedImage(path, rgb.astype(np.float32) / 255.0, "srgb", 8, "photo")
    if rgb.dtype == np.uint16:
        return DecodedImage(path, rgb.astype(np.float32) / 65535.0, "srgb", 16, "photo")
    if rgb.dtype in (np.float32, np.float64):
        require_finite_samples(path, rgb)
        return DecodedImage(path, rgb.astype(np.float32), "linear", 32, "photo")
    raise InputError(f"{path}: unsupported sample type {rgb.dtype}; save it as 8- or 16-bit")


def probe_photo(path: Path) -> ImageHeader:
    """Size, channels and bit depth from the file header (EXIF rotation accounted for)."""
    read_file_bytes(path)
    source = oiio.ImageInput.open(str(path))
    if source is None:
        raise InputError(f"{path}: cannot read image header ({oiio.geterror().strip()}); replace or remove the file")
    try:
        spec = source.spec()
        width, height = spec.width, spec.height
        if spec.get_int_attribute("Orientation", 1) in _TRANSPOSING_ORIENTATIONS:
            width, height = height, width
        bits = {oiio.UINT8: 8, oiio.UINT16: 16, oiio.HALF: 16, oiio.FLOAT: 32}.get(spec.format.basetype, 8)
        encoding = "linear" if spec.format.basetype in (oiio.HALF, oiio.FLOAT) else "srgb"
        return ImageHeader(path, width, height, spec.nchannels, bits, "photo", encoding)
    finally:
        source.close()
