import torch

from lumos3d_cli.model.appearance.local_correction import LOCAL_MAX_STOPS, bound_log_gain, upsample_log_gain


def test_bound_is_zero_at_zero_and_holds_for_huge_values():
    assert float(bound_log_gain(torch.zeros(3)).abs().max()) == 0
    values = bound_log_gain(torch.tensor([-1e9, -3.0, 3.0, 1e9]))
    assert bool((values.abs() <= LOCAL_MAX_STOPS).all()) and bool(torch.isfinite(values).all())


def test_constant_grid_upsamples_to_the_constant():
    grid = torch.full((2, 1, 8, 8), 0.7)
    torch.testing.assert_close(upsample_log_gain(grid, 37, 53), torch.full((2, 1, 37, 53), 0.7))


def test_upsampling_is_smooth_and_stays_within_the_bound():
    # A checkerboard at the bound is the worst case for bicubic overshoot.
    grid = LOCAL_MAX_STOPS * (torch.arange(8)[:, None] + torch.arange(8)[None]).remainder(2).float().mul(2).sub(1)
    out = upsample_log_gain(grid[None, None], 256, 256)
    assert float(out.abs().max()) <= LOCAL_MAX_STOPS
    # Neighbouring pixels differ by far less than a cell's jump (2 * bound over 32 pixels).
    assert float((out[..., 1:] - out[..., :-1]).abs().max()) < 4 * LOCAL_MAX_STOPS / 32 * 2
