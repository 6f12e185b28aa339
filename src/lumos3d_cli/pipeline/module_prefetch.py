"""Import, on a background thread, the modules a restore needs later, and load the rasterizer's
compiled kernels, while structure-from-motion leaves a core idle.

COLMAP matches and maps on one thread (for a repeatable result, geometry/colmap_run.py) and
pycolmap releases the GIL meanwhile, so the second core is free for a few seconds. Two loads cost
a restore that much later on: the preview's writer imports trimesh (0.5 s) and the first render
loads numba's compiled kernels (0.35 s, render/kernel_warm_up.py). Done here, the main thread
finds the modules in sys.modules (Python's import lock makes it wait for a module still being
imported, never import it twice) and the kernels loaded (numba's compiler lock likewise). A
failure is left for the main thread to meet and report.
"""

from __future__ import annotations

import importlib
import logging
import threading
from collections.abc import Sequence

from lumos3d_cli.render.kernel_warm_up import load_compiled_kernels

logger = logging.getLogger(__name__)

WRITING_MODULES = ("trimesh",)  # what writing the outputs imports


def _load_all(modules: Sequence[str]) -> None:
    for name in modules:
        try:
            importlib.import_module(name)
        except Exception:  # the main thread imports it again and reports what is wrong
            logger.debug("prefetching %s failed", name, exc_info=True)
    try:
        load_compiled_kernels()
    except Exception:  # the main thread's first render meets it again
        logger.debug("loading the rasterizer's kernels failed", exc_info=True)


def prefetch_modules(modules: Sequence[str] = WRITING_MODULES) -> threading.Thread:
    """Start importing `modules`, then loading the rasterizer's kernels, on a daemon thread and
    return it (joining it is optional)."""
    thread = threading.Thread(target=_load_all, args=(tuple(modules),), name="lumos3d-prefetch", daemon=True)
    thread.start()
    return thread
