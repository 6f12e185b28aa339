"""JPEG, PNG, TIFF, WebP and BMP through OpenCV (EXIF orientation applied, alpha dropped with a
warning where it hides pixels); the grey TIFFs OpenCV misreads through OpenImageIO."""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import OpenImageIO as oiio

from lumos3d_cli.checks import count_non_finite
from lumos3d_cli.errors import InputError, NonFiniteError
from lumos3d_cli.io.image_types import DecodedImage, ImageHeader
from lumos3d_cli.io.native_messages import pass_on, with_native_messages

# IMREAD_COLOR applies EXIF orientation, turns grayscale into 3 channels and drops alpha;
# IMREAD_ANYDEPTH keeps 16-bit and float samples.
_READ_FLAGS = cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH
_TRANSPOSING_ORIENTATIONS = {5, 6, 7, 8}
_ALPHA_SUFFIXES = {".png", ".tif", ".tiff", ".webp"}  # the photo formats that can carry alpha
_TIFF_SUFFIXES = {".tif", ".tiff"}
# OpenCV's default decoding limits (CV_IO_MAX_IMAGE_WIDTH/HEIGHT and _PIXELS): imdecode raises beyond them
OPENCV_MAX_SIDE = 1 << 20
OPENCV_MAX_PIXELS = 1 << 30
# libjpeg's warnings of damaged data (it decodes on, filling in garbage or grey): a bad Huffman or
# arithmetic code, a segment or the file ending early, a lost restart marker
_JPEG_CORRUPTION = ("Corrupt JPEG data", "Premature end of JPEG file")
# ... but stray bytes before the end marker may be padding an editor left (`_is_end_padding`)
_JPEG_STRAY_BYTES = re.compile(r"(\d+) extraneous bytes before marker 0x([0-9a-fA-F]{2})")
# what the decoders print (libjpeg, libpng, OpenCV's log): read here, not passed on
_DECODER_MESSAGES = (*_JPEG_CORRUPTION, "libpng ", "[ WARN:", "[ERROR:", "Invalid SOS")

logger = logging.getLogger(__name__)
_warned_profiles: set[str] = set()


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


@dataclass(frozen=True)
class _Header:
    """What a photo's header says that OpenCV's decoding does not apply: an alpha channel, its
    EXIF orientation, the name of an embedded ICC colour profile, and a PNG's gAMA of 1 (linear);
    and its size, for OpenCV's limits, and whether OpenCV misreads its samples (`grey_tiff`: a
    one-channel float TIFF it refuses, a grey one with alpha it reads at 8 bits)."""

    has_alpha: bool = False
    orientation: int = 1
    profile: str | None = None
    linear: bool = False
    width: int = 0
    height: int = 0
    grey_tiff: bool = False


def _header(path: Path) -> _Header:
    """The file's `_Header`; the defaults for headers this library cannot read (the decoder judges those)."""
    source = oiio.ImageInput.open(str(path))
    if source is None:
        oiio.geterror()  # retrieved, or OpenImageIO prints it at exit
        return _Header()
    try:
        spec = source.spec()
        has_alpha = path.suffix.lower() in _ALPHA_SUFFIXES and (spec.alpha_channel >= 0 or spec.nchannels in (2, 4))
        profile = spec.get_string_attribute("ICCProfile:profile_description") or None
        linear = path.suffix.lower() == ".png" and spec.get_string_attribute("oiio:ColorSpace").startswith("lin_")
        floats = spec.format.basetype in (oiio.HALF, oiio.FLOAT, oiio.DOUBLE)
        grey_tiff = path.suffix.lower() in _TIFF_SUFFIXES and (spec.nchannels == 2 or (spec.nchannels == 1 and floats))
        return _Header(has_alpha, spec.get_int_attribute("Orientation", 1), profile, linear, spec.width, spec.height,
                       grey_tiff)
    finally:
        source.close()


def _warn_of_a_colour_profile(path: Path, profile: str | None) -> None:
    """A warning naming a photo's colour profile other than sRGB: its pixels are read as sRGB, so
    an Adobe RGB or Display P3 photo's colours come out duller or shifted (17 % less chroma for
    Adobe RGB); no colour-management library is among the dependencies to convert it."""
    if profile is None or "srgb" in profile.casefold().replace(" ", "") or profile in _warned_profiles:
        return
    _warned_profiles.add(profile)  # a phone's photo set shares one profile: said once, not per photo
    logger.warning("%s: its colour profile is %r (said once for every photo with it); lumos3d reads the pixels as "
                   "sRGB, so their colours come out duller or shifted: convert the photos to sRGB first", path, profile)


def _decode(path: Path, data: np.ndarray, header: _Header) -> tuple[np.ndarray | None, np.ndarray | None]:
    """`_decode_pixels`, with what libjpeg and libpng print while decoding captured: a JPEG whose
    data is corrupt is an InputError naming the file (OpenCV returns its garbage as an image); a
    file OpenCV cannot decode at all gets this module's one line, not the library's own as well."""
    try:
        (bgr, alpha), printed = with_native_messages(lambda: _decode_pixels(path, data, header))
    except cv2.error as error:  # a check of OpenCV's own failing (most return no image instead)
        raise InputError(f"{path}: OpenCV cannot decode it ({error.err}); downscale it where it is that large, else "
                         "convert it to an 8- or 16-bit PNG, or leave it out") from None
    lines = printed.splitlines(keepends=True)
    # what another thread printed meanwhile goes where it was going
    pass_on("".join(line for line in lines if not line.startswith(_DECODER_MESSAGES)))
    if bgr is None:
        return bgr, alpha  # read_photo's one line says it
    reports = [line.strip() for line in lines if line.startswith(_JPEG_CORRUPTION)]
    corrupt = [line for line in reports if not _is_end_padding(line, data)]
    if corrupt:
        raise InputError(f"{path}: the JPEG data is corrupt ({corrupt[0].rstrip('.')}): the decoded image would hold "
                         "garbage; replace the file or leave it out")
    if reports:
        logger.warning("%s: libjpeg reports %s: padding before its end marker, which it skipped", path,
                       reports[0].removeprefix("Corrupt JPEG data: ").rstrip("."))
    return bgr, alpha


def _is_end_padding(report: str, data: np.ndarray) -> bool:
    """Whether libjpeg's `report` of stray bytes is about padding an editor left before the end
    marker (bytes 0x00 or 0xFF just before the file's last FF D9, the image intact) rather than
    image data it stopped decoding early (damage: the bytes before the end are entropy-coded data)."""
    found = _JPEG_STRAY_BYTES.search(report)
    if found is None or found.group(2).lower() != "d9":
        return False
    count, raw = int(found.group(1)), data.tobytes()
    end = raw.rfind(b"\xff\xd9")
    return 0 < count <= end and set(raw[end - count: end]) <= {0x00, 0xFF}


def _decode_pixels(path: Path, data: np.ndarray, header: _Header) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(BGR [H, W, 3] as OpenCV's colour decoding gives it, alpha [H, W] or None). A photo with
    alpha is decoded once, unchanged, where no EXIF rotation applies (OpenCV's colour decoding
    drops alpha and turns grey into three channels: the same done here); a rotated one twice."""
    if header.grey_tiff:
        return _decode_grey_tiff(path)
    has_alpha, orientation = header.has_alpha, header.orientation
    if has_alpha and orientation == 1:
        pixels = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if pixels is not None and pixels.ndim == 3 and pixels.shape[2] in (2, 4):
            colour = pixels[..., :-1]
            bgr = np.repeat(colour, 3, axis=2) if colour.shape[2] == 1 else np.ascontiguousarray(colour)
            return bgr, pixels[..., -1]
    bgr = cv2.imdecode(data, _READ_FLAGS)
    alpha = None
    if has_alpha and bgr is not None:
        pixels = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if pixels is not None and pixels.ndim == 3 and pixels.shape[2] in (2, 4):
            alpha = pixels[..., -1]
    return bgr, alpha


def _decode_grey_tiff(path: Path) -> tuple[np.ndarray | None, np.ndarray | None]:
    """`_decode_pixels` of a grey TIFF (one channel, or grey and alpha) through OpenImageIO, at its
    own sample type, its orientation applied; (None, None) where it cannot be decoded."""
    source = oiio.ImageBuf(str(path))
    # read now, not lazily: a truncated strip fails here, where a lazy read filled it with zeros
    pixels = None
    if source.read(0, 0, True) and not source.has_error:
        oriented = oiio.ImageBufAlgo.reorient(source)
        pixels = None if oriented.has_error else oriented.get_pixels(source.spec().format)
        oriented.geterror()
    if pixels is None:
        oiio.geterror()  # retrieved, or OpenImageIO prints them at exit; read_photo's one line says it
        source.geterror()
        return None, None
    if pixels.dtype == np.float16:  # as OpenCV decodes half floats
        pixels = pixels.astype(np.float32)
    grey = np.ascontiguousarray(np.repeat(pixels[..., :1], 3, axis=2))
    return grey, pixels[..., 1] if pixels.shape[2] == 2 else None


def _warn_of_transparency(path: Path, alpha: np.ndarray | None) -> None:
    """A warning when alpha hides some pixels: alpha is dropped, so whatever colour lies under
    them is restored as part of the photo."""
    if alpha is None:
        return
    hidden = float(np.mean(alpha < np.iinfo(alpha.dtype).max if alpha.dtype.kind == "u" else alpha < 1))
    if hidden > 0:
        logger.warning("%s: %.1f %% of its pixels are transparent or partly so; alpha is ignored, so the colour under them is "
                       "restored too: flatten the image onto a background first to choose that colour", path, 100 * hidden)


def read_photo(path: Path) -> DecodedImage:
    """Decode a photo to RGB float32: [0, 1] sRGB for 8/16-bit files, linear for float TIFFs."""
    data = read_file_bytes(path)
    header = _header(path)
    if max(header.width, header.height) > OPENCV_MAX_SIDE or header.width * header.height > OPENCV_MAX_PIXELS:
        raise InputError(f"{path}: {header.width}x{header.height} pixels is beyond what OpenCV decodes (at most "
                         f"{OPENCV_MAX_SIDE:,} a side and {OPENCV_MAX_PIXELS:,} pixels); crop or downscale it")
    bgr, alpha = _decode(path, data, header)
    if bgr is None:
        raise InputError(
            f"{path}: cannot decode as {path.suffix.lstrip('.').upper()} (corrupt, truncated or not an image); "
            "replace or remove the file"
        )
    _warn_of_transparency(path, alpha)
    _warn_of_a_colour_profile(path, header.profile)
    rgb = np.ascontiguousarray(bgr[..., ::-1])
    encoding = "linear" if header.linear else "srgb"  # a PNG whose gAMA says its codes are linear light
    if rgb.dtype == np.uint8:
        return DecodedImage(path, rgb.astype(np.float32) / 255.0, encoding, 8, "photo")
    if rgb.dtype == np.uint16:
        return DecodedImage(path, rgb.astype(np.float32) / 65535.0, encoding, 16, "photo")
    if rgb.dtype in (np.float32, np.float64):
        require_finite_samples(path, rgb)
        return DecodedImage(path, rgb.astype(np.float32), "linear", 32, "photo")
    raise InputError(f"{path}: unsupported sample type {rgb.dtype}; save it as unsigned 8- or 16-bit, or as float")


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
        # float64 is decoded to float32 (read_photo): reported as what is read
        bits = {oiio.UINT8: 8, oiio.UINT16: 16, oiio.HALF: 16, oiio.FLOAT: 32, oiio.DOUBLE: 32}.get(spec.format.basetype, 8)
        encoding = "linear" if spec.format.basetype in (oiio.HALF, oiio.FLOAT, oiio.DOUBLE) else "srgb"
        return ImageHeader(path, width, height, spec.nchannels, bits, "photo", encoding)
    finally:
        source.close()
