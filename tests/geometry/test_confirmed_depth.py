import torch

from lumos3d_cli.geometry.confirmed_depth import confirmed_pixels, neighbours_by_distance, projected_cover
from lumos3d_cli.model.geometry import unproject_depth

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


def test_projected_cover_marks_the_pixels_points_land_on_grown_by_one():
    cameras = plane_cameras(2)
    depth = plane_depth(cameras)
    world = unproject_depth(depth.float(), cameras.extrinsics.float(), cameras.intrinsics.float())
    cover = projected_cover(world[0][5, 7][None], cameras, 0, (32, 48))  # the point of view 0's pixel (row 5, col 7)
    expected = torch.zeros(32, 48, dtype=torch.bool)
    expected[4:7, 6:9] = True
    assert torch.equal(cover, expected)
    behind = 2 * cameras.centers()[0].float() - world[0][5, 7]  # mirrored through the camera centre: behind it
    assert not bool(projected_cover(behind[None], cameras, 0, (32, 48)).any())


def test_a_contradicted_pixel_is_dropped_only_where_the_neighbours_cover_its_place():
    cameras = plane_cameras(5)
    depth = plane_depth(cameras)
    depth[0, 8:24, 12:36] *= 0.6
    kept = confirmed_pixels(depth, cameras)
    world = unproject_depth(depth.float(), cameras.extrinsics.float(), cameras.intrinsics.float())
    for view in range(5):
        covered = torch.zeros(32, 48, dtype=torch.bool)
        for other in neighbours_by_distance(cameras, 4)[view].tolist():
            covered |= projected_cover(world[other][kept[other]], cameras, view, (32, 48))
        assert bool(covered[~kept[view]].all())
    assert bool(kept[0].float().mean() < 1)


def test_a_contradicted_pixel_whose_place_no_neighbour_covers_is_kept():
    # View 1 (3 units to the right) sees a far wall through its left half: it contradicts view 0's
    # plane from column ~23 on, but its wall lands on view 0 only up to column ~34 (7 px of
    # parallax at 3x the distance); its plane, seen through its right half, from column ~45 on.
    cameras = plane_cameras(2)
    depth = plane_depth(cameras)
    depth[1, :, :24] *= 3
    kept = confirmed_pixels(depth, cameras)
    assert bool(kept[0, :, 36:45].all())  # contradicted, but dropping them would leave a hole
    assert float(kept[0, :, 24:34].float().mean()) < 0.3  # contradicted and covered by the wall
    assert bool(kept[1].all())
