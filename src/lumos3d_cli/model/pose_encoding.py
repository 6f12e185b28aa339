"""VGGT's camera encoding "absT_quaR_FoV" <-> extrinsics and intrinsics.

Nine numbers per camera: translation t of the world->camera transform (3), its rotation as a
quaternion in **xyzw** order (4; the rest of the project uses wxyz, so this module reorders at
the boundary), vertical then horizontal field of view in radians (2). The principal point is the
image centre (W/2, H/2), which with the project's pixel-centre convention (+0.5) is the exact
optical centre of the image.
"""

from __future__ import annotations

import math

import torch

from lumos3d_cli.rotations import matrix_to_quaternion, quaternion_to_matrix, unit_quaternions

POSE_ENCODING_SIZE = 9
# Fields of view are clamped into this open range before decoding so that a degenerate
# prediction (ReLU'd to 0, or near 180 degrees) still yields a finite, positive focal length.
MIN_FOV = 1e-3
MAX_FOV = math.pi - 1e-3


def xyzw_to_wxyz(quats: torch.Tensor) -> torch.Tensor:
    """[..., 4] scalar-last (VGGT's order) -> [..., 4] scalar-first."""
    return quats[..., [3, 0, 1, 2]]


def wxyz_to_xyzw(quats: torch.Tensor) -> torch.Tensor:
    """[..., 4] scalar-first -> [..., 4] scalar-last (VGGT's order)."""
    return quats[..., [1, 2, 3, 0]]


def normalize_quaternion(quats: torch.Tensor, identity_first: bool = True) -> torch.Tensor:
    """Unit quaternions [..., 4]; (near-)zero inputs become the identity (w = 1, at index 0 for
    wxyz when `identity_first`, else at index 3 for xyzw; `rotations.unit_quaternions`)."""
    if identity_first:
        return unit_quaternions(quats)
    return wxyz_to_xyzw(unit_quaternions(xyzw_to_wxyz(quats)))


def encode_pose(extrinsics: torch.Tensor, intrinsics: torch.Tensor, image_size_hw: tuple[int, int]) -> torch.Tensor:
    """extrinsics [..., 3, 4] world->camera, intrinsics [..., 3, 3] -> encoding [..., 9] (float32).

    The principal point is not encoded (it is assumed to be the image centre).
    """
    height, width = image_size_hw
    quats = wxyz_to_xyzw(matrix_to_quaternion(extrinsics[..., :3, :3]))  # w >= 0, as VGGT
    translation = extrinsics[..., :3, 3]
    fov_h = 2 * torch.atan((height / 2) / intrinsics[..., 1, 1])
    fov_w = 2 * torch.atan((width / 2) / intrinsics[..., 0, 0])
    return torch.cat((translation, quats, fov_h[..., None], fov_w[..., None]), dim=-1).float()


def decode_pose(encoding: torch.Tensor, image_size_hw: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """encoding [..., 9] -> (extrinsics [..., 3, 4] world->camera, intrinsics [..., 3, 3]) in
    pixels of an image of size (H, W). The quaternion need not be normalised."""
    height, width = image_size_hw
    translation, quats, fov = encoding[..., :3], encoding[..., 3:7], encoding[..., 7:9]
    rotation = quaternion_to_matrix(xyzw_to_wxyz(normalize_quaternion(quats, identity_first=False)))
    extrinsics = torch.cat((rotation, translation[..., None]), dim=-1)
    fov = fov.clamp(MIN_FOV, MAX_FOV)
    fy = (height / 2) / torch.tan(fov[..., 0] / 2)
    fx = (width / 2) / torch.tan(fov[..., 1] / 2)
    zero, one = torch.zeros_like(fx), torch.ones_like(fx)
    rows = (fx, zero, torch.full_like(fx, width / 2), zero, fy, torch.full_like(fx, height / 2), zero, zero, one)
    intrinsics = torch.stack(rows, dim=-1).unflatten(-1, (3, 3))
    return extrinsics, intrinsics
