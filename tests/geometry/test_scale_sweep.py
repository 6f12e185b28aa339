"""The global depth scale swept against the photos (geometry/scale_sweep.py): the oracle is the
synthetic plane's exact depth, given to the sweep divided by a known factor."""

import math

import pytest
import torch

from lumos3d_cli.errors import NonFiniteError
from lumos3d_cli.geometry.scale_sweep import MAX_PIXELS, MIN_CONTRAST, STEPS_PER_OCTAVE, sweep_depth_scale
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.model.geometry import unproject_depth

from synthetic_scene import plane_cameras, plane_depth, plane_texture

WIDTH, HEIGHT = 96, 64


def _scene(views: int = 6, width: int = WIDTH, height: int = HEIGHT):
    cameras = plane_cameras(views, width, height)
    depth = plane_depth(cameras)
    world = unproject_depth(depth, cameras.extrinsics, cameras.intrinsics)
    return cameras, depth, plane_texture(world).permute(0, 3, 1, 2).float()


@pytest.mark.parametrize("factor", [1e-6, 0.02, 1.0, 37.0, 1e6])
def test_the_sweep_finds_the_scale_the_photos_agree_on(factor):
    """Depth in any unit against the given cameras' (the grid follows the depth's own median)
    comes back within a tenth of a step of the grid (2**(1/4): 19 %)."""
    cameras, truth, images = _scene()
    swept = sweep_depth_scale(truth / factor, cameras, images)
    assert swept.scale is not None and swept.contrast > 0.2 and swept.candidates == 49
    assert abs(math.log(swept.scale / factor)) < 0.1 * math.log(2) / STEPS_PER_OCTAVE
    summary = swept.summary()
    assert summary["form"] == "photo-consistency scale" and summary["scale"] == swept.scale


def test_only_the_views_taking_part_are_scored():
    """Held-out views (evaluation's) are neither scored nor compared with: with their photos made
    noise, the scale is still found; with two views left, a scale; with one, none."""
    cameras, truth, images = _scene()
    noisy = images.clone()
    noisy[[1, 3]] = torch.rand_like(images[[1, 3]])
    taking_part = [True, False, True, False, True, True]
    swept = sweep_depth_scale(truth / 5, cameras, noisy, taking_part)
    assert abs(math.log(swept.scale / 5)) < 0.5 * math.log(2) / STEPS_PER_OCTAVE  # fewer views: within half a step
    assert sweep_depth_scale(truth / 5, cameras, images, [True, True, False, False, False, False]).scale is not None
    lone = sweep_depth_scale(truth / 5, cameras, images, [True] + [False] * 5)
    assert lone.scale is None and lone.candidates == 0


def test_photos_that_agree_on_nothing_give_no_scale():
    """Black, clipped or textureless photos (and cameras at one centre) fix no scale: None, for the
    caller's fallback, rather than the best of noise."""
    cameras, truth, images = _scene()
    for flat in (torch.zeros_like(images), torch.ones_like(images)):
        swept = sweep_depth_scale(truth, cameras, flat)
        assert swept.scale is None and swept.contrast < MIN_CONTRAST
    one_centre = cameras.extrinsics.clone()
    one_centre[:, :, 3] = -(one_centre[:, :, :3] @ cameras.centers()[0])  # t = -R c for the first camera's c
    rotations_only = type(cameras)(one_centre, cameras.intrinsics, cameras.sizes, cameras.names)
    assert sweep_depth_scale(truth, rotations_only, images).scale is None



def test_far_from_the_origin_bracketed_and_large_views_keep_the_scale():
    """Poses a million units from the origin (a geodetic frame) lost the cameras' spacing to
    float32 rounding (5e6: the scene put 15x too far, accepted); each position shot twice (an
    exposure bracket) gave a spacing of 0 and no sweep; views beyond MAX_PIXELS are averaged down."""
    cameras, truth, images = _scene()
    shifted = cameras.extrinsics.clone()
    shifted[:, :, 3] -= shifted[:, :, :3] @ torch.tensor([5e6, 5e6, 0.0], dtype=torch.float64)  # centres + (5e6, 5e6, 0)
    far = Cameras(shifted, cameras.intrinsics, cameras.sizes, cameras.names)
    assert abs(math.log(sweep_depth_scale(truth / 5, far, images).scale / 5)) < 0.03
    twice = [view for view in range(len(cameras)) for _ in range(2)]
    bracketed = Cameras(cameras.extrinsics[twice], cameras.intrinsics[twice], [cameras.sizes[0]] * len(twice))
    assert abs(math.log(sweep_depth_scale(truth[twice] / 5, bracketed, images[twice]).scale / 5)) < 0.03
    cameras, truth, images = _scene(width=2 * WIDTH, height=2 * HEIGHT)
    assert 4 * WIDTH * HEIGHT > MAX_PIXELS
    assert abs(math.log(sweep_depth_scale(truth / 5, cameras, images).scale / 5)) < 0.03


def test_noise_the_views_do_not_share_and_non_finite_depth():
    """Independent noise in every photo (a score of the best of noise) gives no scale; NaN or Inf
    depth is refused, not swept into a fallback or a scale."""
    cameras, truth, images = _scene()
    assert sweep_depth_scale(truth, cameras, torch.rand(images.shape, generator=torch.Generator().manual_seed(1))).scale is None
    for bad in (math.nan, math.inf):
        depth = truth.clone()
        depth[0, 0, 0] = bad
        with pytest.raises(NonFiniteError):
            sweep_depth_scale(depth, cameras, images)


def test_a_view_whose_depth_is_off_from_the_others_takes_its_own_scale():
    """The network's depth is in one frame only nearly (Herz-Jesus: the views' own best scales
    spread over 10.8-15.3): one scale for all left a view's Gaussians beside the others'."""
    cameras, truth, images = _scene()
    depth = truth / 5
    depth[2] = truth[2] / 6.5  # this view's depth 30 % short of the others'
    swept = sweep_depth_scale(depth, cameras, images)
    assert abs(math.log(swept.scale / 5)) < 0.1
    own = swept.view_scales
    assert abs(math.log(float(own[2]) / 6.5)) < 0.05
    assert all(abs(math.log(float(own[v]) / 5)) < 0.05 for v in (0, 1, 3, 4, 5))
    assert swept.summary()["views_with_their_own_scale"] >= 1
