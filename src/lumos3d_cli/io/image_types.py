"""Plain records shared by the image readers."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

Encoding = Literal["srgb", "linear"]


@dataclass(frozen=True)
class DecodedImage:
    """One decoded image file.

    pixels: [H, W, 3] float32, RGB. sRGB-encoded in [0, 1] for photos; linear light (may
    exceed 1) for RAW, EXR/HDR and float TIFF.
    """

    path: Path
    pixels: np.ndarray
    encoding: Encoding
    bit_depth: int  # bits per channel in the file (8, 16, 32 for float)
    kind: str  # 'photo', 'hdr' or 'raw'


@dataclass(frozen=True)
class ImageHeader:
    """What a file says about itself without decoding its pixels (size after EXIF rotation)."""

    path: Path
    width: int
    height: int
    channels: int
    bit_depth: int
    kind: str
    encoding: Encoding
