"""Views rendered one per thread (render/view_threads.py): the same results as one view after
another, in order, with single-threaded kernels inside the workers."""

import threading

import numba
import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.pipeline.restore import render_views
from lumos3d_cli.render.contribution import rendered_weights
from lumos3d_cli.render.kernel_warm_up import load_compiled_kernels
from lumos3d_cli.render.view_threads import kernel_threads, map_views

from factories import camera_at_origin, random_scene


def _cameras(count: int, width: int = 160, height: int = 120) -> Cameras:  # above the one-thread size
    first = camera_at_origin(width, height)
    views = []
    for index in range(count):
        extrinsics = first.extrinsics.clone()
        extrinsics[0, 0, 3] = 0.05 * index  # each view a little further to the left
        views.append(Cameras(extrinsics, first.intrinsics, first.sizes))
    return Cameras.concatenate(views)


class _TorchThreads:
    """torch's intra-op thread count set for a block (the test workers run on one)."""

    def __init__(self, count: int):
        self.count, self.before = count, torch.get_num_threads()

    def __enter__(self):
        torch.set_num_threads(self.count)

    def __exit__(self, *exc):
        torch.set_num_threads(self.before)


def test_map_views_keeps_the_order_and_gives_each_worker_one_kernel_thread(monkeypatch):
    load_compiled_kernels()  # a parallel kernel has run: numba's threading layer is chosen
    seen = []

    def record(index: int) -> tuple[int, int]:
        seen.append(threading.current_thread().name)
        return index, kernel_threads()

    with _TorchThreads(2):
        assert kernel_threads() == 2
        assert list(map_views(record, 7, torch.device("cpu"))) == [(index, 1) for index in range(7)]
        assert all(name.startswith("lumos3d-view") for name in seen)
        assert kernel_threads() == 2  # the caller's own count is untouched
        seen.clear()
        # another device (gsplat on CUDA) renders one view after another, on the caller's thread
        assert list(map_views(record, 3, torch.device("meta"))) == [(index, 2) for index in range(3)]
        assert set(seen) == {threading.current_thread().name}
    with _TorchThreads(1):
        seen.clear()
        assert list(map_views(record, 3, torch.device("cpu"))) == [(index, 1) for index in range(3)]
        assert set(seen) == {threading.current_thread().name}
    # numba's workqueue layer takes no kernels from two threads at once: one view after another
    monkeypatch.setattr(numba, "threading_layer", lambda: "workqueue")
    with _TorchThreads(2):
        seen.clear()
        assert list(map_views(record, 3, torch.device("cpu"))) == [(index, 2) for index in range(3)]
        assert set(seen) == {threading.current_thread().name}


def test_weights_and_views_rendered_one_per_thread_equal_one_after_another():
    gaussians = random_scene(3000, 4, degree=1)
    cameras = _cameras(6)
    serial_weights = rendered_weights(gaussians, cameras)
    serial_views = render_views(gaussians, cameras, None, fill=True)
    with _TorchThreads(2):
        threaded_weights = rendered_weights(gaussians, cameras)
        threaded_views = render_views(gaussians, cameras, None, fill=True)
    assert torch.equal(threaded_weights, serial_weights) and bool((serial_weights > 0).any())
    assert threaded_views.unobserved == serial_views.unobserved
    for threaded, serial in zip(threaded_views.images, serial_views.images, strict=True):
        assert torch.equal(threaded, serial)
