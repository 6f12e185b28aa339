import torch

from lumos3d_cli.io.camera_files import read_cameras
from lumos3d_cli.render.camera_paths import axes_meeting_point, look_at, orbit_from_cameras, orbit_from_gaussians

from factories import random_scene


def _target_pixels(cameras, target):
    pixels, depth = cameras.project(target[None].double())
    return pixels[:, 0], depth[:, 0]


def test_look_at_puts_the_target_at_the_principal_point():
    positions = torch.randn(10, 3, dtype=torch.float64) * 5
    target = torch.tensor([0.5, -1.0, 2.0], dtype=torch.float64)
    up = torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)
    extrinsics = look_at(positions, target, up)
    rotation = extrinsics[:, :, :3]
    torch.testing.assert_close(rotation @ rotation.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(10, 3, 3))
    assert torch.allclose(torch.linalg.det(rotation), torch.ones(10, dtype=torch.float64))
    camera_target = (rotation @ target[:, None])[..., 0] + extrinsics[:, :, 3]
    torch.testing.assert_close(camera_target[:, :2], torch.zeros(10, 2, dtype=torch.float64), atol=1e-12, rtol=0)
    assert (camera_target[:, 2] > 0).all()
    assert ((rotation[:, 1, :] @ up) < 0).all()  # image "down" points away from world up


def test_orbit_around_an_object_capture(shared_data):
    cameras = read_cameras(shared_data / "scenes" / "kitchen")
    orbit = orbit_from_cameras(cameras, 24, 320, 214)
    assert len(orbit) == 24 and orbit.sizes == [(320, 214)] * 24
    target = axes_meeting_point(cameras.centers().double(), cameras.extrinsics[:, 2, :3].double())
    assert target is not None
    pixels, depth = _target_pixels(orbit, target)  # the orbit looks where the input cameras look
    assert (depth > 0).all()
    torch.testing.assert_close(pixels, torch.tensor([[160.0, 107.0]], dtype=torch.float64).expand(24, 2), atol=1.0, rtol=0)
    radius = (orbit.centers() - orbit.centers().mean(dim=0)).norm(dim=1)
    assert radius.std() / radius.mean() < 1e-6  # a circle
    distances = (cameras.centers() - target).norm(dim=1)
    assert distances.min() * 0.9 < (orbit.centers() - target).norm(dim=1).mean() < distances.max() * 1.1


def test_forward_facing_capture_gets_a_small_circle(shared_data):
    cameras = read_cameras(shared_data / "scenes" / "llff_fern")
    orbit = orbit_from_cameras(cameras, 10, 256, 192)
    spread = (cameras.centers() - cameras.centers().mean(dim=0)).norm(dim=1).max()
    distance = (orbit.centers() - cameras.centers().mean(dim=0)).norm(dim=1)
    assert (distance <= spread * 1.0001).all()
    mean_forward = cameras.extrinsics[:, 2, :3].mean(dim=0)
    assert ((orbit.extrinsics[:, 2, :3] @ mean_forward) > 0.8).all()  # still looking into the scene


def test_orbit_from_bounds_sees_the_scene():
    gaussians = random_scene(500, 0, dtype=torch.float32)
    orbit = orbit_from_gaussians(gaussians, 8, 64, 64)
    centre = gaussians.means.median(dim=0).values.double()
    pixels, depth = _target_pixels(orbit, centre)
    assert (depth > 0).all()
    torch.testing.assert_close(pixels, torch.full((8, 2), 32.0, dtype=torch.float64), atol=1.0, rtol=0)
