"""OpenEXR and Radiance HDR through OpenImageIO, as linear RGB."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.image_types import DecodedImage, ImageHeader
from lumos3d_cli.io.photo import read_file_bytes, require_finite_samples


_HDR_FORMATS = {"openexr": "OpenEXR", "hdr": "Radiance HDR"}
_SUFFIX_FORMATS = {".exr": "openexr", ".hdr": "hdr"}


def _open(path: Path) -> oiio.ImageInput:
    read_file_bytes(path)
    source = oiio.ImageInput.open(str(path))
    if source is None:
        raise InputError(f"{path}: cannot open ({oiio.geterror().strip()}); replace or remove the file")
    # OpenImageIO picks its decoder by the content: a JPEG named .exr would be read as linear light
    # and its sRGB values encoded a second time
    found = source.format_name()
    if found not in _HDR_FORMATS:
        source.close()
        raise InputError(f"{path}: is a {found} file, not {_HDR_FORMATS[_SUFFIX_FORMATS[path.suffix.lower()]]}; "
                         "give it its own suffix (.jpg, .png, .tif)")
    return source


def _rgb_channels(path: Path, spec: oiio.ImageSpec) -> list[int]:
    """Indices of R, G, B (by name, else the first three); a grey image's one channel (Y, or the
    only one) repeated. Two channels of colour (R and G, say) are refused: repeating the first
    would drop the other without a word."""
    names = [name.split(".")[-1].upper() for name in spec.channelnames]
    if all(letter in names for letter in "RGB"):
        return [names.index(letter) for letter in "RGB"]
    if spec.nchannels >= 3:
        return [0, 1, 2]
    if "Y" in names:
        return [names.index("Y")] * 3
    if spec.nchannels == 1:
        return [0, 0, 0]
    raise InputError(f"{path}: holds the channels {', '.join(spec.channelnames)}, neither RGB nor grey (Y); save it "
                     "with R, G and B, or with one grey channel")


def read_hdr(path: Path) -> DecodedImage:
    """Decode to [H, W, 3] float32 linear RGB; NaN or Inf anywhere is an InputError."""
    source = _open(path)
    try:
        spec = source.spec()
        pixels = source.read_image(0, 0, 0, spec.nchannels, "float")
        if pixels is None or source.has_error:
            raise InputError(f"{path}: cannot decode ({source.geterror().strip()}); replace or remove the file")
    finally:
        source.close()
    pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
    rgb = np.ascontiguousarray(pixels[..., _rgb_channels(path, spec)])
    require_finite_samples(path, rgb)
    bits = 16 if spec.format.basetype == oiio.HALF else 32
    return DecodedImage(path, rgb, "linear", bits, "hdr")


def probe_hdr(path: Path) -> ImageHeader:
    source = _open(path)
    try:
        spec = source.spec()
        bits = 16 if spec.format.basetype == oiio.HALF else 32
        return ImageHeader(path, spec.width, spec.height, spec.nchannels, bits, "hdr", "linear")
    finally:
        source.close()
