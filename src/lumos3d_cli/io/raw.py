"""Camera RAW through rawpy (LibRaw) as linear, camera-white-balanced RGB."""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
import rawpy

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.image_types import DecodedImage, ImageHeader
from lumos3d_cli.io.native_messages import pass_on, with_native_messages
from lumos3d_cli.io.photo import read_file_bytes


def _convert_hint(path: Path) -> str:
    if path.suffix.lower() == ".dng":
        return "export it as a 16-bit TIFF from a RAW editor"
    return "convert it to DNG (Adobe DNG Converter) or export a 16-bit TIFF"


def _reason(error: rawpy.LibRawError) -> str:
    """LibRaw's reason, readable (it comes as bytes: b'Input/output error')."""
    reason = error.args[0] if error.args else error
    return reason.decode(errors="replace") if isinstance(reason, bytes) else str(reason)


def _refusal(path: Path, action: str, error: rawpy.LibRawError) -> InputError:
    if isinstance(error, (rawpy.LibRawIOError, rawpy.LibRawDataError)):  # what a truncated or damaged file gives
        return InputError(f"{path}: cannot {action} camera RAW: the file is damaged or truncated ({_reason(error)}); "
                          "copy it from the camera or card again")
    if isinstance(error, rawpy.LibRawFileUnsupportedError):
        return InputError(f"{path}: unsupported camera RAW ({_reason(error)}); {_convert_hint(path)}")
    return InputError(f"{path}: cannot {action} camera RAW ({_reason(error)}); {_convert_hint(path)}")


def _open(path: Path) -> rawpy.RawPy:
    read_file_bytes(path)
    try:
        raw, printed = with_native_messages(partial(rawpy.imread, str(path)))
    except rawpy.LibRawError as error:
        raise _refusal(path, "read", error) from error
    pass_on(printed)
    return raw


def read_raw(path: Path) -> DecodedImage:
    """Demosaic to [H, W, 3] float32 linear RGB (sRGB primaries).

    Black level subtracted, the camera's as-shot white balance applied, no auto-brightening,
    no gamma, 16-bit output scaled so the sensor's white level is 1.0.
    """
    with _open(path) as raw:
        decode = partial(raw.postprocess, gamma=(1, 1), no_auto_bright=True, output_bps=16, use_camera_wb=True,
                         output_color=rawpy.ColorSpace.sRGB)
        try:
            # LibRaw prints its own line of a damaged file ("Unexpected end of file") above the one
            # line of the refusal: captured, and passed on only when it decodes nonetheless
            rgb16, printed = with_native_messages(decode)
        except rawpy.LibRawError as error:
            raise _refusal(path, "decode", error) from error
        pass_on(printed)
        left, top, width, height = _default_crop(raw.sizes)
    rgb16 = rgb16[top: top + height, left: left + width]
    return DecodedImage(path, rgb16.astype(np.float32) / 65535.0, "linear", 16, "raw")


def _default_crop(sizes) -> tuple[int, int, int, int]:
    """(left, top, width, height) of the picture a RAW viewer shows within LibRaw's output: the
    file's default crop (a DNG's DefaultCrop: Blackmagic.dng's 4128x2176 sensor area holds a
    4096x2160 picture, its outer columns black or dark), else the whole output. Applied to
    unrotated images only (LibRaw flip 0): no rotated RAW with a crop was at hand to test the
    rotated boxes."""
    whole = (0, 0, sizes.width, sizes.height) if sizes.flip not in (5, 6) else (0, 0, sizes.height, sizes.width)
    box = (sizes.crop_left_margin, sizes.crop_top_margin, sizes.crop_width, sizes.crop_height)
    left, top, width, height = box
    if sizes.flip != 0 or width <= 0 or height <= 0 or left < 0 or top < 0 \
            or left + width > sizes.width or top + height > sizes.height:
        return whole
    return box


def probe_raw(path: Path) -> ImageHeader:
    with _open(path) as raw:
        _, _, width, height = _default_crop(raw.sizes)
        return ImageHeader(path, width, height, 3, 16, "raw", "linear")
