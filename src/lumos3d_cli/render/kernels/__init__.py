"""numba kernels of the CPU rasterizer. Arrays in, arrays out; no torch here."""

import os
from pathlib import Path

import numba

from lumos3d_cli.render.kernels.cache_folder import fallback_cache_folder

# Before any kernel module is imported: numba picks each `cache=True` function's cache folder when
# the function is defined.
_FALLBACK = fallback_cache_folder(Path(__file__).parent, os.environ)
if _FALLBACK is not None:
    numba.config.CACHE_DIR = str(_FALLBACK)
