import torch

from lumos3d_cli.geometry.confirmed_depth import confirmed_pixels, neighbours_by_distance

from synthetic_scene import plane_cameras, plane_depth


def test_exact_depth_keeps_every_pixel():
    cameras = plane_cameras(5)
    assert bool(confirmed_pixels(plane_depth(cameras), cameras).all())


def test_a_floater_in_front_of_the_neighbours_surface_is_dropped_and_a_far_patch_kept():
    cameras = plane_cameras(5)
    depth = plane_depth(cameras)
    floater, hidden = depth.clone(), depth.clone()
    floater[0, 8:24, 12:36] *= 0.6  # 40 % nearer: the neighbours see the plane through it
    hidden[0, 8:24, 12:36] *= 1.6   # behind the plane: occluded from the neighbours, no evidence against it
    kept = confirmed_pixels(floater, cameras)
    assert not bool(kept[0, 10:22, 14:34].any())
    assert bool(kept[1:].all()) and kept[0].float().mean() > 0.5
    assert bool(confirmed_pixels(hidden, cameras).all())


def test_one_view_keeps_everything_and_neighbours_are_the_nearest():
    cameras = plane_cameras(4)
    assert bool(confirmed_pixels(plane_depth(cameras)[:1], cameras[[0]]).all())
    nearest = neighbours_by_distance(cameras, 2)
    assert nearest.shape == (4, 2) and not any(int(v) in nearest[v].tolist() for v in range(4))
    distances = torch.cdist(cameras.centers(), cameras.centers())
    assert all(distances[v, nearest[v, 0]] <= distances[v, nearest[v, 1]] for v in range(4))
