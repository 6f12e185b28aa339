"""Camera RAW through rawpy (LibRaw) as linear, camera-white-balanced RGB."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rawpy

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.image_types import DecodedImage, ImageHeader
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
        return rawpy.imread(str(path))
    except rawpy.LibRawError as error:
        raise _refusal(path, "read", error) from error


def read_raw(path: Path) -> DecodedImage:
    """Demosaic to [H, W, 3] float32 linear RGB (sRGB primaries).

    Black level subtracted, the camera's as-shot white balance applied, no auto-brightening,
    no gamma, 16-bit output scaled so the sensor's white level is 1.0.
    """
    with _open(path) as raw:
        try:
            rgb16 = raw.postprocess(
                gamma=(1, 1),
                no_auto_bright=True,
                output_bps=16,
                use_camera_wb=True,
                output_color=rawpy.ColorSpace.sRGB,
            )
        except rawpy.LibRawError as error:
            raise _refusal(path, "decode", error) from error
    return DecodedImage(path, rgb16.astype(np.float32) / 65535.0, "linear", 16, "raw")


def probe_raw(path: Path) -> ImageHeader:
    with _open(path) as raw:
        sizes = raw.sizes
        width, height = sizes.width, sizes.height
        if sizes.flip in (5, 6):  # LibRaw flip codes that rotate by 90 degrees
            width, height = height, width
        return ImageHeader(path, width, height, 3, 16, "raw", "linear")
