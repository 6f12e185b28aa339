"""Where the CPU rasterizer's threads go: inside one view's kernels, or one view per thread.

By default each numba kernel (projection, binning, compositing) runs on torch's intra-op thread
count. A render of one view of a few hundred thousand Gaussians is short (40-80 ms on 2 cores),
and its parallel regions do not keep every thread busy: the Gaussian budget's 25 views of 821k
Gaussians took 4.6 s on 2 threads and 7.9 s on 1 (a speed-up of 1.7). Views that do not depend
on one another (the budget's weights, the restored views) are therefore rendered one per
thread, each with single-threaded kernels (4.2 s there, the same weights bit for bit: every
view's result is computed alone and combined in view order by the caller).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numba
import torch

Result = TypeVar("Result")

_local = threading.local()


def kernel_threads() -> int:
    """The threads one kernel call may use on this thread: 1 inside `map_views`' workers, else
    torch's intra-op count (capped by NUMBA_NUM_THREADS)."""
    return getattr(_local, "threads", None) or max(1, min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS))


def _single_threaded(function: Callable[[int], Result], index: int) -> Result:
    _local.threads = 1
    try:
        return function(index)
    finally:
        _local.threads = None


def _layer_takes_threads() -> bool:
    """Whether numba's threading layer takes parallel kernels from several threads at once: omp
    and tbb do; workqueue (numba's fallback when neither library is there) does not, nor is any
    layer chosen before the first parallel kernel has run."""
    try:
        return numba.threading_layer() in ("omp", "tbb")
    except ValueError:  # not initialised yet
        return False


def map_views(function: Callable[[int], Result], count: int, device: torch.device) -> Iterator[Result]:
    """function(0), ..., function(count - 1), yielded in order as they are done. On the CPU with
    more than one kernel thread the views run concurrently, one per thread, each with
    single-threaded kernels (module docstring); on another device (gsplat on CUDA), with one
    thread, or where numba's threading layer cannot take kernels from several threads, one after
    another. `function` must not depend on the order its calls run in."""
    workers = min(kernel_threads(), count)
    if device.type != "cpu" or workers <= 1 or not _layer_takes_threads():
        yield from (function(index) for index in range(count))
        return
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="lumos3d-view") as pool:
        yield from pool.map(lambda index: _single_threaded(function, index), range(count))
