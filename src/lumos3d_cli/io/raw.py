"""Camera RAW through rawpy (LibRaw) as linear, camera-white-balanced RGB."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rawpy

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.image_types import DecodedImage, ImageHeader
from lumos3d_cli.io.photo import read_file_bytes

_CONVERT_HINT = "convert it to DNG (Adobe DNG Converter) or export a 16-bit TIFF"


def _open(path: Path) -> rawpy.RawPy:
    read_file_bytes(path)
    try:
        return rawpy.imread(str(path))
    except rawpy.LibRawFileUnsupportedError as error:
        raise InputError(f"{path}: unsupported camera RAW ({error}); {_CONVERT_HINT}") from error
    except rawpy.LibRawError as error:
        raise InputError(f"{path}: cannot read camera RAW ({error}); the file may be corrupt; {_CONVERT_HINT}") from error


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
            raise InputError(f"{path}: cannot decode camera RAW ({error}); {_CONVERT_HINT}") from error
    return DecodedImage(path, rgb16.astype(np.float32) / 65535.0, "linear", 16, "raw")


def probe_raw(path: Path) -> ImageHeader:
    with _open(path) as raw:
        sizes = raw.sizes
        width, height = sizes.width, sizes.height
        if sizes.flip in (5, 6):  # LibRaw flip codes that rotate by 90 degrees
            width, height = height, width
        return ImageHeader(path, width, height, 3, 16, "raw", "linear")
