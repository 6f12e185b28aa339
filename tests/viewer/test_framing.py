import math

import numpy as np
import pytest
import torch

from lumos3d_cli.viewer.framing import VIEWER_RADIUS, frame_scene, view_position_showing

from factories import random_gaussians


def _angles(points, position, up):
    """Tangents of each point's horizontal and vertical angle from the line of sight to the
    origin (an independent look-at frame built from the viewpoint), and its depth."""
    forward = -position / np.linalg.norm(position)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    relative = points - position
    depth = relative @ forward
    return np.abs(relative @ right) / depth, np.abs(relative @ true_up) / depth, depth


def test_a_long_lens_scene_moves_the_view_back_until_every_camera_shows():
    # cameras 32 units in front of a radius-10 scene, spread sideways, a 19-degree lens: a view
    # 5 units behind them sees none of them
    rng = np.random.default_rng(0)
    cameras = np.column_stack([rng.uniform(-3, 2, 8), rng.uniform(-1.5, -0.9, 8), rng.uniform(-33, -29, 8)])
    up, fov = np.array([0.0, -1.0, 0.0]), math.radians(19.0)
    start = cameras.mean(axis=0) + np.array([4.0, -3.0, -5.0])
    horizontal, vertical, _ = _angles(cameras, start, up)
    assert np.max(np.maximum(horizontal, vertical)) > math.tan(fov / 2)  # the naive start misses them
    position = view_position_showing(cameras, start, up, fov)
    horizontal, vertical, depth = _angles(cameras, position, up)
    assert np.all(depth > 0) and np.all(np.maximum(horizontal, vertical) <= math.tan(0.8 * fov / 2) + 1e-9)
    # on the same ray, and no further than needed: one step (1.15) closer, a camera falls outside
    assert np.allclose(position / np.linalg.norm(position), start / np.linalg.norm(start))
    horizontal, vertical, depth = _angles(cameras, position / 1.15, up)
    assert np.any(depth <= 0) or np.max(np.maximum(horizontal, vertical)) > math.tan(0.8 * fov / 2)


def test_a_view_that_already_shows_the_cameras_stays_where_it_is():
    cameras = np.array([[0.0, 0.0, -10.0], [0.5, 0.2, -10.5]])
    start = np.array([0.3, -0.5, -20.0])
    assert np.array_equal(view_position_showing(cameras, start, np.array([0.0, -1.0, 0.0]), math.radians(50)), start)


def test_cameras_behind_the_starting_view_are_brought_in_front():
    cameras = np.array([[0.0, 0.0, -30.0], [1.0, 0.0, -31.0]])
    start = np.array([0.0, 0.0, -12.0])
    position = view_position_showing(cameras, start, np.array([0.0, -1.0, 0.0]), math.radians(40))
    assert np.all(_angles(cameras, position, np.array([0.0, -1.0, 0.0]))[2] > 0)


def test_one_gaussian_or_many_at_one_point_is_framed_by_its_size():
    """The radius of a single Gaussian's centre is 0: the frame fell back to a scale of 1, and a
    Gaussian of sigma 0.05 showed as a dot some 25 viewer units away."""
    gaussians = random_gaussians(5, 0)
    gaussians.means[:] = torch.tensor([1.0, 2.0, 3.0])
    gaussians.scales[:] = 0.05
    frame = frame_scene(gaussians, None)
    assert frame.scale == pytest.approx(VIEWER_RADIUS / 0.15)
    assert torch.allclose(frame.centre, torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
