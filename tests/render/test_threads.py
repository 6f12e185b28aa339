import numba
import torch

from lumos3d_cli.render.render import render

from factories import camera_at_origin, random_scene


def test_kernel_uses_torch_thread_count_and_is_deterministic():
    gaussians = random_scene(3000, 0, dtype=torch.float32)
    previous = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        single = render(gaussians, camera_at_origin(192, 144)).images
        assert numba.get_num_threads() == 1
        torch.set_num_threads(max(2, previous))
        multi = render(gaussians, camera_at_origin(192, 144)).images
        assert numba.get_num_threads() == min(max(2, previous), numba.config.NUMBA_NUM_THREADS)
    finally:
        torch.set_num_threads(previous)
    assert torch.equal(single, multi)
