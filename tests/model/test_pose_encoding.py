import math

import torch

from lumos3d_cli.io.cameras import make_intrinsics
from lumos3d_cli.model.pose_encoding import decode_pose, encode_pose, normalize_quaternion
from lumos3d_cli.rotations import quaternion_to_matrix

from factories import random_cameras


def test_round_trip_of_random_cameras_with_centred_principal_point():
    cameras = random_cameras(20, seed=4)
    height, width = 241, 320
    intrinsics = cameras.intrinsics.clone()
    intrinsics[:, 0, 2], intrinsics[:, 1, 2] = width / 2, height / 2
    encoding = encode_pose(cameras.extrinsics, intrinsics, (height, width))
    assert encoding.shape == (20, 9) and encoding.dtype == torch.float32
    assert (encoding[:, 6] >= 0).all()  # w (last, xyzw) standardised non-negative, as VGGT
    extrinsics, decoded = decode_pose(encoding.double(), (height, width))
    torch.testing.assert_close(extrinsics, cameras.extrinsics, atol=1e-6, rtol=1e-6)
    torch.testing.assert_close(decoded, intrinsics, atol=1e-4, rtol=1e-6)


def test_encoding_by_hand_rotation_about_z_and_ninety_degree_fields_of_view():
    angle = 0.7
    rotation = torch.tensor([[math.cos(angle), -math.sin(angle), 0], [math.sin(angle), math.cos(angle), 0], [0, 0, 1.0]])
    extrinsics = torch.cat((rotation, torch.tensor([[1.0], [2.0], [3.0]])), dim=1)
    height, width = 100, 200
    intrinsics = make_intrinsics(width / 2, height / 2, width / 2, height / 2)[0].float()  # fov 90 deg both ways
    encoding = encode_pose(extrinsics, intrinsics, (height, width))
    expected = [1, 2, 3, 0, 0, math.sin(angle / 2), math.cos(angle / 2), math.pi / 2, math.pi / 2]
    torch.testing.assert_close(encoding, torch.tensor(expected), atol=1e-6, rtol=0)


def test_fov_order_is_height_then_width():
    encoding = torch.tensor([0, 0, 0, 0, 0, 0, 1, 2 * math.atan(0.5), 2 * math.atan(0.25)])
    _, intrinsics = decode_pose(encoding, (100, 300))
    # fy = (H/2)/tan(fov_h/2) = 50/0.5, fx = (W/2)/tan(fov_w/2) = 150/0.25
    torch.testing.assert_close(intrinsics[1, 1], torch.tensor(100.0))
    torch.testing.assert_close(intrinsics[0, 0], torch.tensor(600.0))
    torch.testing.assert_close(intrinsics[:2, 2], torch.tensor([150.0, 50.0]))


def test_degenerate_encodings_decode_to_valid_finite_cameras():
    encoding = torch.zeros(3, 9)
    encoding[1, 3:7] = torch.tensor([0.0, 0.0, 0.0, -5.0])  # un-normalised
    encoding[2, 7:] = 4.0  # fov beyond 180 degrees
    extrinsics, intrinsics = decode_pose(encoding, (10, 20))
    assert torch.isfinite(extrinsics).all() and torch.isfinite(intrinsics).all()
    identity = torch.eye(3).expand(3, 3, 3)
    torch.testing.assert_close(extrinsics[..., :3], identity)  # zero quaternion -> identity, -w -> identity
    assert (intrinsics[:, 0, 0] > 0).all() and (intrinsics[:, 1, 1] > 0).all()


def test_unnormalised_quaternions_decode_like_normalised_ones():
    quats = torch.randn(50, 4)
    encoding = torch.cat((torch.zeros(50, 3), quats * 7.5, torch.ones(50, 2)), dim=1)
    extrinsics, _ = decode_pose(encoding, (8, 8))
    expected = quaternion_to_matrix(quats[:, [3, 0, 1, 2]])
    torch.testing.assert_close(extrinsics[..., :3], expected, atol=1e-5, rtol=0)
    torch.testing.assert_close(normalize_quaternion(quats * 3).norm(dim=-1), torch.ones(50))
