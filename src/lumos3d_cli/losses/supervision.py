"""Ground-truth supervision of the normal-light teacher stage: dataset cameras (as pose
encodings, every refinement weighted as in distillation) and sparse COLMAP depth."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from lumos3d_cli.losses.distillation import weighted_pose_huber
from lumos3d_cli.model.pose_encoding import encode_pose


def pose_supervision(
    pose_enc_list: list[torch.Tensor], extrinsics: torch.Tensor, intrinsics: torch.Tensor, image_size_hw: tuple[int, int],
    has_poses: torch.Tensor,
) -> torch.Tensor:
    """Huber between predicted encodings [B, V, 9] per refinement and the encoding of the
    dataset cameras (extrinsics [B, V, 3, 4] relative to view 0, intrinsics [B, V, 3, 3]);
    scenes without poses (has_poses [B] False) are left out."""
    if not bool(has_poses.any()):
        return pose_enc_list[-1].sum() * 0.0
    target = encode_pose(extrinsics[has_poses], intrinsics[has_poses], image_size_hw)
    return weighted_pose_huber([p[has_poses] for p in pose_enc_list], [target] * len(pose_enc_list))


def sparse_depth_supervision(depth: torch.Tensor, sparse_depth: torch.Tensor) -> torch.Tensor:
    """Huber between predicted depth and sparse points, on pixels holding a point; [B, V, H, W]."""
    valid = sparse_depth > 0
    if not bool(valid.any()):
        return depth.sum() * 0.0
    return F.huber_loss(depth[valid], sparse_depth[valid], delta=1.0)
