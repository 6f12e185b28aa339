import numba
import torch

from lumos3d_cli.render import rasterizer
from lumos3d_cli.render.render import render

from factories import camera_at_origin, random_scene


def test_kernel_uses_torch_thread_count_and_is_deterministic(monkeypatch):
    gaussians = random_scene(3000, 0, dtype=torch.float32)
    previous = torch.get_num_threads()
    try:
        seen = []
        original = rasterizer.rasterize_forward

        def counting(*args):  # the count the compositing kernel runs with
            seen.append(numba.get_num_threads())
            return original(*args)

        monkeypatch.setattr(rasterizer, "rasterize_forward", counting)
        torch.set_num_threads(1)
        single = render(gaussians, camera_at_origin(192, 144)).images
        assert torch.get_num_threads() == 1  # numba's OpenMP layer, started by a process's first kernel, made it 2
        torch.set_num_threads(max(2, previous))
        multi = render(gaussians, camera_at_origin(192, 144)).images
        assert seen == [1, min(max(2, previous), numba.config.NUMBA_NUM_THREADS)]
        # the caller's own count is put back (a render left the user's numba code on one thread)
        numba.set_num_threads(1)
        render(gaussians, camera_at_origin(192, 144))
        assert numba.get_num_threads() == 1
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        torch.set_num_threads(1)
        render(gaussians, camera_at_origin(192, 144))
        assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS
    finally:
        torch.set_num_threads(previous)
    assert torch.equal(single, multi)
