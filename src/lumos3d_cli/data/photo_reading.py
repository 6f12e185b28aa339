"""Training images read from disk: a file holding NaN or Inf is bad data, an InputError naming it,
not the NonFiniteError of a step's computation, which the trainer skips as a non-finite step
(a photo of NaN samples skipped every step that drew it, and the run ended "final", exit 0)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lumos3d_cli.errors import InputError, NonFiniteError
from lumos3d_cli.io.images import read_image, to_srgb


def read_training_photo(path: Path) -> np.ndarray:
    """[H, W, 3] float32 sRGB in [0, 1] of the image file `path` (`io.images.read_image`)."""
    try:
        return to_srgb(read_image(path))
    except NonFiniteError as error:
        raise InputError(str(error)) from None
