import math

import pytest
import torch
import torch.nn.functional as F

from lumos3d_cli.errors import NonFiniteError
from lumos3d_cli.geometry.photo_consistency import box_mean, depth_agreement, sweep_depth, triangulation_angles
from lumos3d_cli.geometry.sweep_settings import DepthSweepSettings
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.model.geometry import unproject_depth

from synthetic_scene import plane_cameras, plane_depth, plane_texture

WIDTH, HEIGHT = 96, 64


def _scene(views: int = 5):
    cameras = plane_cameras(views, WIDTH, HEIGHT)
    depth = plane_depth(cameras)
    world = unproject_depth(depth, cameras.extrinsics, cameras.intrinsics)  # [V, h, w, 3]
    images = plane_texture(world).permute(0, 3, 1, 2).float()
    return cameras, depth, images


def _biased(depth: torch.Tensor) -> torch.Tensor:
    """A smooth error of 4-8 % (what alignment to sparse points leaves on fine structure)."""
    ramp = torch.linspace(0.04, 0.08, depth.shape[-1], dtype=depth.dtype)
    return depth * (1 + ramp)


def test_box_mean_matches_average_pooling_of_the_replicated_border():
    values = torch.rand(2, 3, 17, 23, dtype=torch.float64)
    for radius in (1, 2, 4):
        expected = F.avg_pool2d(F.pad(values, (radius,) * 4, mode="replicate"), 2 * radius + 1, stride=1)
        assert torch.allclose(box_mean(values, radius), expected, atol=1e-12)


def test_the_sweep_moves_biased_depth_onto_the_textured_plane():
    cameras, truth, images = _scene()
    biased = _biased(truth)
    swept = sweep_depth(biased, cameras, images)
    before = ((biased - truth).abs() / truth)[:, 4:-4, 4:-4]
    after = ((swept.depth - truth).abs() / truth)[:, 4:-4, 4:-4]
    assert swept.depth.dtype == truth.dtype and swept.depth.shape == truth.shape
    assert float(before.median()) > 0.04
    assert float(after.median()) < 0.005  # a step of the sweep is 3 %: the parabola lands within a fraction of it
    # the edge of the overlap and windows that leave a neighbour's photo keep the bias (11 %
    # here; a rule asking 0.1 above the old depth's score instead of contrast left 26 %)
    assert float((after > 0.02).float().mean()) < 0.15
    assert swept.share > 0.6
    # what did not change is exactly the input
    assert torch.equal(swept.depth[~swept.changed], biased[~swept.changed])


def test_depth_already_right_stays_within_a_fraction_of_a_step():
    cameras, truth, images = _scene()
    swept = sweep_depth(truth, cameras, images)
    error = ((swept.depth - truth).abs() / truth)[:, 4:-4, 4:-4]  # at the border the windows run off the photos
    assert float(error.median()) < 0.002
    # a wrong depth wins only where a window leaves a neighbour's photo and the periodic texture repeats
    assert float((error > 0.015).float().mean()) < 0.005


@pytest.mark.parametrize("shrink", [0.1, 0.03, 0.01])
def test_views_too_close_together_for_the_depth_change_nothing(shrink):
    """The same cameras moved towards each other (centres x shrink): a depth change of the sweep's
    span (25 %) then moves a window by a pixel or two, the score is nearly the same at every
    depth, and its best is the photos' noise. The sweep must leave the depth as it was, right or
    biased: the angle rule finds no neighbour (under 3 degrees); without it the contrast rule and
    the neighbours' agreement still keep all but a few pixels; with none of the three it moves
    most pixels (the test's own check that the case is the hard one)."""
    spread = plane_cameras(5, WIDTH, HEIGHT)
    extrinsics = spread.extrinsics.clone()
    extrinsics[:, :, 3] *= shrink  # t = -R c: the centres scale with it
    cameras = Cameras(extrinsics, spread.intrinsics, spread.sizes, spread.names)
    truth = plane_depth(cameras)
    world = unproject_depth(truth, cameras.extrinsics, cameras.intrinsics)
    noise = 0.01 * torch.randn(5, 3, HEIGHT, WIDTH, generator=torch.Generator().manual_seed(1))
    images = (plane_texture(world).permute(0, 3, 1, 2).float() + noise).clamp(0, 1)
    for start in (truth, _biased(truth)):
        swept = sweep_depth(start, cameras, images)
        assert torch.equal(swept.depth, start) and swept.share == 0.0 and swept.views_without_neighbours == 5
        contrast_only = sweep_depth(start, cameras, images, DepthSweepSettings(min_angle=0.0))
        assert contrast_only.share < 0.01 and contrast_only.views_without_neighbours == 0
    no_rule = DepthSweepSettings(min_contrast=0.0, min_angle=0.0, max_disagreement=0.0)
    assert sweep_depth(truth, cameras, images, no_rule).share > 0.5


def test_triangulation_angles_match_the_geometry():
    """Three cameras along a line before a plane: each pair's angle at the point on the row view's
    axis at its median depth, against the angle between the two rays computed here on its own;
    0 for a view with itself; the same for a scene 10^4 times larger."""
    cameras = plane_cameras(3, WIDTH, HEIGHT)
    depth = plane_depth(cameras)
    angles = triangulation_angles(cameras, depth)
    centres = cameras.centers()
    rotation = cameras.extrinsics[:, :, :3]
    for view in range(3):
        point = centres[view] + depth[view].flatten().median() * rotation[view, 2]
        for other in set(range(3)) - {view}:  # arccos, the oracle, is inexact near 0 degrees
            own, seen = point - centres[view], point - centres[other]
            expected = math.degrees(math.acos(max(-1.0, min(1.0, float((own @ seen) / (own.norm() * seen.norm()))))))
            assert float(angles[view, other]) == pytest.approx(expected, abs=1e-5)
    assert torch.all(angles.diagonal() < 1e-12)
    scaled = cameras.to(torch.float64)
    extrinsics = scaled.extrinsics.clone()
    extrinsics[:, :, 3] *= 1e4
    huge = Cameras(extrinsics, scaled.intrinsics, list(cameras.sizes), list(cameras.names))
    assert torch.allclose(triangulation_angles(huge, depth * 1e4), angles, atol=1e-6)


def test_a_view_seen_only_at_wide_angles_keeps_its_depth():
    """A sixth camera far to the side of the five (30 degrees and more from each at its scene):
    square windows there no longer cover the same surface, so it takes no neighbour, keeps its
    depth and is counted; the five are swept as before, never compared with it."""
    cameras, truth, images = _scene()
    extrinsics = cameras.extrinsics.clone()
    far = torch.cat([extrinsics, extrinsics[-1:]])
    far[-1, :, 3] = -(far[-1, :, :3] @ torch.tensor([6.0, 0.0, 0.0], dtype=far.dtype))
    wide = Cameras(far, torch.cat([cameras.intrinsics, cameras.intrinsics[-1:]]), [*cameras.sizes, cameras.sizes[-1]],
                   [*cameras.names, "far.png"])
    wide_truth = plane_depth(wide)
    world = unproject_depth(wide_truth, wide.extrinsics, wide.intrinsics)
    wide_images = plane_texture(world).permute(0, 3, 1, 2).float()
    assert float(triangulation_angles(wide, wide_truth)[5, :5].min()) > DepthSweepSettings().max_angle
    biased = _biased(wide_truth)
    swept = sweep_depth(biased, wide, wide_images)
    assert torch.equal(swept.depth[5], biased[5]) and swept.views_without_neighbours == 1
    assert torch.equal(swept.depth[:5], sweep_depth(biased[:5], cameras, images).depth)


def test_a_new_depth_stays_only_where_a_neighbour_agrees():
    """View 0's depth 5 % off on its left half, right on its right half; every pixel marked new.
    Against the neighbours' right depth, only the right half agrees, and that half only where it
    lands in a neighbour's photo: checked against world points projected here on their own
    (camera x = R X + t, the nearest pixel of the neighbour's depth map), at any scene scale."""
    cameras, truth, _ = _scene()
    depth = truth.clone()
    depth[0, :, : WIDTH // 2] *= 1.05
    changed = torch.ones(depth.shape, dtype=torch.bool)
    changed[1:] = False
    neighbours = [[1, 2], [0], [0], [], []]
    agreed = depth_agreement(depth.float(), changed, cameras.to(torch.float32), neighbours, 0.02)
    world = unproject_depth(depth[:1], cameras.extrinsics[:1], cameras.intrinsics[:1])[0]  # [h, w, 3]
    expected = torch.zeros(HEIGHT, WIDTH, dtype=torch.bool)
    for other in (1, 2):
        local = world @ cameras.extrinsics[other, :, :3].T + cameras.extrinsics[other, :, 3]
        k = cameras.intrinsics[other]
        u = k[0, 0] * local[..., 0] / local[..., 2] + k[0, 2]
        v = k[1, 1] * local[..., 1] / local[..., 2] + k[1, 2]
        inside = (local[..., 2] > 0) & (u > 0) & (u < WIDTH) & (v > 0) & (v < HEIGHT)
        column, row = u.floor().long().clamp(0, WIDTH - 1), v.floor().long().clamp(0, HEIGHT - 1)
        theirs = truth[other][row, column]
        expected |= inside & ((local[..., 2] - theirs).abs() <= 0.02 * theirs)
    assert not agreed[1:].any()  # what did not change is never kept as new
    assert not agreed[0, :, : WIDTH // 2].any()
    assert float(agreed[0, :, WIDTH // 2:].float().mean()) > 0.5
    # float32 against float64 at the edges of the neighbours' photos: a handful of pixels
    assert float((agreed[0] != expected).float().mean()) < 0.005
    scaled = cameras.to(torch.float64)
    extrinsics = scaled.extrinsics.clone()
    extrinsics[:, :, 3] *= 1e4
    huge = Cameras(extrinsics, scaled.intrinsics, list(cameras.sizes), list(cameras.names)).to(torch.float32)
    assert float((depth_agreement((depth * 1e4).float(), changed, huge, neighbours, 0.02) != agreed).float().mean()) < 0.005


def test_neighbours_that_disagree_keep_the_old_depth():
    """With the agreement check the biased scene is still swept onto the plane (the views agree
    on it), and what the check takes back is exactly the input."""
    cameras, truth, images = _scene()
    biased = _biased(truth)
    checked = sweep_depth(biased, cameras, images)
    unchecked = sweep_depth(biased, cameras, images, DepthSweepSettings(max_disagreement=0.0))
    assert checked.share > 0.6 and checked.share <= unchecked.share
    assert not (checked.changed & ~unchecked.changed).any()
    assert torch.equal(checked.depth[checked.changed], unchecked.depth[checked.changed])
    assert torch.equal(checked.depth[~checked.changed], biased[~checked.changed])


@pytest.mark.parametrize("fill", [0.0, 1.0, 0.37])
def test_flat_black_and_clipped_photos_change_nothing(fill):
    cameras, truth, _ = _scene()
    biased = _biased(truth)
    swept = sweep_depth(biased, cameras, torch.full((5, 3, HEIGHT, WIDTH), fill))
    assert torch.equal(swept.depth, biased) and swept.share == 0.0


@pytest.mark.parametrize("level", [0.02, 0.98])
def test_near_flat_dark_and_clipped_photos_with_faint_noise_change_nothing(level):
    """Windows of a dark or clipped photo with noise far under a grey level have no texture: the
    float32 window sums must not turn their rounding into matches (at the network's grid size)."""
    cameras = plane_cameras(5, 224, 168)
    depth = plane_depth(cameras)
    noise = torch.rand(5, 3, 168, 224, generator=torch.Generator().manual_seed(3)) - 0.5
    swept = sweep_depth(depth, cameras, level + 1e-3 * noise)
    assert swept.share == 0.0 and torch.equal(swept.depth, depth)


def test_noise_the_neighbours_do_not_share_changes_little():
    cameras, truth, _ = _scene()
    noise = torch.rand(5, 3, HEIGHT, WIDTH, generator=torch.Generator().manual_seed(1))
    swept = sweep_depth(truth, cameras, noise)
    assert swept.share < 0.05


def test_held_out_views_are_never_compared_with():
    cameras, truth, images = _scene()
    biased = _biased(truth)
    allowed = [True, True, False, True, True]
    swept = sweep_depth(biased, cameras, images, neighbour_views=allowed)
    scrambled = images.clone()
    scrambled[2] = torch.rand(3, HEIGHT, WIDTH, generator=torch.Generator().manual_seed(2))
    again = sweep_depth(biased, cameras, scrambled, neighbour_views=allowed)
    others = [0, 1, 3, 4]
    assert torch.equal(swept.depth[others], again.depth[others])
    assert torch.equal(swept.depth[2], biased[2])  # the held-out view itself is not swept
    assert swept.share > 0.5  # of the views that take part
    # a view whose only allowed neighbour is missing keeps its depth
    alone = sweep_depth(biased, cameras, images, neighbour_views=[True, False, False, False, False])
    assert torch.equal(alone.depth[0], biased[0])


def test_one_view_keeps_its_depth():
    cameras, truth, images = _scene()
    swept = sweep_depth(truth[:1], cameras[[0]], images[:1])
    assert torch.equal(swept.depth, truth[:1]) and swept.share == 0.0


def test_huge_and_tiny_scenes_give_the_same_relative_depth():
    cameras, truth, images = _scene()
    biased = _biased(truth)
    reference = sweep_depth(biased, cameras, images).depth / truth
    for scale in (1e-4, 1e4):
        scaled = cameras.to(torch.float64)
        extrinsics = scaled.extrinsics.clone()
        extrinsics[:, :, 3] *= scale
        moved = type(cameras)(extrinsics, scaled.intrinsics, list(cameras.sizes), list(cameras.names))
        result = sweep_depth(biased * scale, moved, images).depth / (truth * scale)
        assert torch.allclose(result, reference, atol=2e-3)


def test_bad_inputs_are_refused():
    cameras, truth, images = _scene()
    with pytest.raises(ValueError, match="positive"):
        sweep_depth(truth * 0, cameras, images)
    bad = images.clone()
    bad[0, 0, 0, 0] = float("nan")
    with pytest.raises(NonFiniteError, match="images"):
        sweep_depth(truth, cameras, bad)
    with pytest.raises(ValueError, match="must match"):
        sweep_depth(truth, cameras, images[:3])
    for settings in (dict(hypotheses=4), dict(span=1.5), dict(best=5, neighbours=4), dict(radius=0), dict(min_contrast=-0.1),
                     dict(min_angle=-1.0), dict(min_angle=20.0, max_angle=15.0), dict(max_angle=200.0),
                     dict(max_disagreement=-0.01), dict(max_disagreement=1.0)):
        with pytest.raises(ValueError):
            DepthSweepSettings(**settings)
