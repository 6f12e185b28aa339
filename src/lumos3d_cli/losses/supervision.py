"""Ground-truth supervision of the normal-light teacher stage, as VGGT is trained: dataset cameras
(VGGT's camera loss on the pose encodings, every refinement weighted as in distillation) and
sparse COLMAP depth (VGGT's confidence-aware depth loss)."""

from __future__ import annotations

import torch

from lumos3d_cli.losses.distillation import iteration_weights
from lumos3d_cli.model.pose_encoding import encode_pose

FOCAL_WEIGHT = 0.5  # VGGT's weight of the field-of-view part
CONFIDENCE_REGULARISER = 0.2  # VGGT's alpha


def camera_l1(prediction: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """VGGT's camera loss of one refinement, encodings [N, 9]: mean L1 of the translation, plus
    that of the quaternion, plus FOCAL_WEIGHT times that of the field of view.

    L1 rather than the distillation's Huber (delta 1): the encodings differ by far less than 1,
    where Huber is quadratic and a 30 degree rotation error costs ~0.003 — too little for the
    camera head to learn against the rendering and depth terms.
    """
    error = (prediction - target).abs()
    return error[..., :3].mean() + error[..., 3:7].mean() + FOCAL_WEIGHT * error[..., 7:].mean()


def pose_supervision(
    pose_enc_list: list[torch.Tensor], extrinsics: torch.Tensor, intrinsics: torch.Tensor, image_size_hw: tuple[int, int],
    has_poses: torch.Tensor,
) -> torch.Tensor:
    """`camera_l1` between predicted encodings [B, V, 9] per refinement and the encoding of the
    dataset cameras (extrinsics [B, V, 3, 4] relative to view 0, intrinsics [B, V, 3, 3]),
    refinement i of N weighted 0.6^(N-i-1), averaged over refinements; scenes without poses
    (has_poses [B] False) are left out."""
    if not bool(has_poses.any()):
        return pose_enc_list[-1].sum() * 0.0
    target = encode_pose(extrinsics[has_poses], intrinsics[has_poses], image_size_hw).detach()
    weights = iteration_weights(len(pose_enc_list))
    total = sum(w * camera_l1(p[has_poses], target) for w, p in zip(weights, pose_enc_list))
    return total / len(pose_enc_list)


def sparse_depth_supervision(depth: torch.Tensor, confidence: torch.Tensor, sparse_depth: torch.Tensor) -> torch.Tensor:
    """VGGT's confidence-aware depth loss on the pixels holding a sparse point, all [B, V, H, W]:
    mean of |depth - point| * confidence - CONFIDENCE_REGULARISER * log(confidence).

    This is what trains the depth head's confidence (> 1), which the student's depth
    distillation uses to pick the teacher's reliable pixels.
    """
    valid = sparse_depth > 0
    if not bool(valid.any()):
        return (depth.sum() + confidence.sum()) * 0.0
    error = (depth[valid] - sparse_depth[valid]).abs()
    return (error * confidence[valid] - CONFIDENCE_REGULARISER * confidence[valid].log()).mean()
