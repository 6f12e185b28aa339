"""Fitting a scene to a Gaussian budget: what goes (unseen, weak, over the cap) and what stays."""

import pytest
import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.render.gaussian_budget import BudgetReport, fit_budget, select_budget

from factories import camera_at_origin, random_scene


def _scene_with_outcasts():
    """30 Gaussians in front of the camera; 0-2 behind it, 3-4 far to the side, 5-6 transparent."""
    gaussians = random_scene(30, 0, degree=1)
    gaussians.means[0:3, 2] = -3.0
    gaussians.means[3:5, 0] = 100.0
    gaussians.opacities[5:7] = 0.0
    return gaussians


def test_gaussians_no_camera_draws_are_dropped_and_the_rest_kept_in_order():
    gaussians = _scene_with_outcasts()
    kept, report = fit_budget(gaussians, camera_at_origin(40, 30), min_weight=0.0)
    assert report == BudgetReport(kept=23, dropped_unseen=7, dropped_weak=0, capped=0)
    torch.testing.assert_close(kept.means, gaussians.means[7:])
    assert report.as_dict() == {"kept": 23, "dropped_unseen": 7, "dropped_weak": 0, "capped": 0}


def test_a_gaussian_seen_by_a_second_camera_stays():
    gaussians = _scene_with_outcasts()
    behind = camera_at_origin(40, 30)
    behind.extrinsics[0, 0, 0] = behind.extrinsics[0, 2, 2] = -1.0  # turned around: sees z < 0
    kept, report = fit_budget(gaussians, Cameras.concatenate([camera_at_origin(40, 30), behind]), min_weight=0.0)
    assert report.dropped_unseen == 4 and len(kept) == 26


def test_weak_gaussians_go_below_the_threshold():
    weights = torch.tensor([0.0, 0.05, 0.3, 2.0, 7.0, 0.5])
    keep, report = select_budget(weights, min_weight=0.5)
    assert keep.tolist() == [False, False, False, True, True, True]
    assert report == BudgetReport(kept=3, dropped_unseen=1, dropped_weak=2, capped=0)


@pytest.mark.parametrize("cap", [1, 2, 6, 9, 20])
def test_max_gaussians_is_respected_exactly_keeping_the_strongest(cap):
    weights = torch.tensor([3.0, 0.0, 9.0, 1.0, 1.0, 4.0, 0.2, 7.0, 1.0, 5.0])
    keep, report = select_budget(weights, min_weight=0.1, max_gaussians=cap)
    survivors = 9  # weight >= 0.1
    assert report.kept == int(keep.sum()) == min(cap, survivors)
    assert report.capped == max(0, survivors - cap)
    if cap < survivors:
        assert weights[keep].min() >= weights[~keep & (weights >= 0.1)].max()
    if cap == 6:  # three tied at 1.0 compete for the last place: the lowest index wins
        assert keep.nonzero().squeeze(1).tolist() == [0, 2, 3, 5, 7, 9]
    if cap == 2:
        assert keep.nonzero().squeeze(1).tolist() == [2, 7]


def test_fit_budget_caps_a_rendered_scene_exactly():
    gaussians = random_scene(60, 1, degree=0)
    kept, report = fit_budget(gaussians, camera_at_origin(32, 24), max_gaussians=17, min_weight=0.0)
    assert len(kept) == report.kept == 17
    assert report.kept + report.dropped_unseen + report.dropped_weak + report.capped == 60


def test_bad_budgets_are_refused():
    gaussians = random_scene(4, 0)
    with pytest.raises(ValueError, match="max_gaussians"):
        fit_budget(gaussians, camera_at_origin(8, 8), max_gaussians=0)
    with pytest.raises(ValueError, match="min_weight"):
        fit_budget(gaussians, camera_at_origin(8, 8), min_weight=-1.0)
    with pytest.raises(ValueError, match="at least one camera"):
        fit_budget(gaussians, camera_at_origin(8, 8)[[]])


def test_empty_scene():
    kept, report = fit_budget(random_scene(0, 0), camera_at_origin(16, 12), max_gaussians=5)
    assert len(kept) == 0 and report == BudgetReport(0, 0, 0, 0)


@pytest.mark.parametrize("scale", [1e-6, 1e3])
def test_tiny_and_huge_scales(scale):
    gaussians = random_scene(20, 2, degree=1)
    gaussians.scales[:10] = scale
    kept, report = fit_budget(gaussians, camera_at_origin(24, 18))
    assert all(torch.isfinite(t).all() for t in kept.tensors().values())
    assert report.kept + report.dropped_unseen + report.dropped_weak == 20
    if scale > 1:  # huge ones cover the image: whichever is nearest stays
        assert report.kept >= 1


def test_all_transparent():
    gaussians = random_scene(10, 3, degree=0)
    gaussians.opacities[:] = 0.0
    kept, report = fit_budget(gaussians, camera_at_origin(16, 12), max_gaussians=3)
    assert len(kept) == 0 and report.dropped_unseen == 10


def test_a_view_smaller_than_the_grid_counts_its_weights_in_grid_pixels():
    """Weights are pixels of each view: a 64x48 photo under the network's 224x168 grid of pixel
    Gaussians shows each at a twelfth of a pixel, so all fell under the 0.5 px threshold and 57 %
    of every view went uncovered. Counted in the grid's pixels, they stay; views at least as
    large as the grid count as before."""
    from lumos3d_cli.render.contribution import rendered_weights

    gaussians = random_scene(300, 4, degree=0, dtype=torch.float32, spread=0.5)
    gaussians.scales[:] = 0.004
    small = camera_at_origin(32, 24)
    plain = rendered_weights(gaussians, small)
    torch.testing.assert_close(rendered_weights(gaussians, small, at_least_pixels=4 * 32 * 24), 4 * plain)
    torch.testing.assert_close(rendered_weights(gaussians, small, at_least_pixels=16 * 12), plain)
    kept_plain, _ = fit_budget(gaussians, small)
    kept_grid, _ = fit_budget(gaussians, small, grid_pixels=16 * 32 * 24)
    assert len(kept_grid) > len(kept_plain)
