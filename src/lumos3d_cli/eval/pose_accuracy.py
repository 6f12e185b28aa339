"""Camera-pose accuracy against reference cameras, as VGGT and PoseDiffusion report it.

For every pair of views (i, j), i < j: the relative rotation error (the angle of
R_ij^pred^T R_ij^ref) and the relative translation direction error (the angle between the
predicted and reference directions of t_ij, up to sign, so scale-free); RRA@t / RTA@t are the
fractions of pairs below t degrees, AUC@t the mean over thresholds 1..t degrees of the fraction
of pairs whose larger error is below the threshold. Both camera sets are world->camera
extrinsics [V, 3, 4] in any world frame and scale: only relative poses are compared.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch

from lumos3d_cli.geometry.vector_angles import angle_between

_EPS = 1e-12


@dataclass
class PoseAccuracy:
    """Summary over the view pairs (errors in degrees)."""

    pairs: int
    rotation_error_median: float
    translation_error_median: float
    rra_15: float
    rta_15: float
    auc_30: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def _rotation_angle(rotations: torch.Tensor) -> torch.Tensor:
    """Rotation angle in degrees of matrices [P, 3, 3], from the trace and the skew part."""
    trace = rotations.diagonal(dim1=-2, dim2=-1).sum(-1)
    skew = torch.stack((rotations[:, 2, 1] - rotations[:, 1, 2], rotations[:, 0, 2] - rotations[:, 2, 0],
                        rotations[:, 1, 0] - rotations[:, 0, 1]), dim=-1)
    return torch.rad2deg(torch.atan2(skew.norm(dim=-1), trace - 1))


def relative_pose_errors(predicted: torch.Tensor, reference: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """extrinsics [V, 3, 4] each -> (rotation errors, translation direction errors) [P] in
    degrees, P = V(V-1)/2. A pair whose reference (or predicted) cameras share one centre has no
    translation direction: its translation error is 90 degrees (the worst, up to sign)."""
    if predicted.shape != reference.shape or predicted.dim() != 3 or predicted.shape[1:] != (3, 4):
        raise ValueError(f"expected two extrinsics [V, 3, 4] of one shape, got {tuple(predicted.shape)} and {tuple(reference.shape)}")
    first, second = torch.triu_indices(predicted.shape[0], predicted.shape[0], offset=1)
    errors = []
    for cameras in (predicted.double(), reference.double()):
        rotation, translation = cameras[:, :, :3], cameras[:, :, 3]
        relative = rotation[second] @ rotation[first].transpose(-1, -2)
        direction = translation[second] - (relative @ translation[first, :, None])[..., 0]
        errors.append((relative, direction))
    (predicted_rotation, predicted_direction), (reference_rotation, reference_direction) = errors
    rotation_error = _rotation_angle(predicted_rotation.transpose(-1, -2) @ reference_rotation)
    angle = angle_between(predicted_direction, reference_direction)
    translation_error = torch.minimum(angle, 180 - angle)
    degenerate = (predicted_direction.norm(dim=-1) < _EPS) | (reference_direction.norm(dim=-1) < _EPS)
    translation_error = torch.where(degenerate, torch.full_like(translation_error, 90.0), translation_error)
    return rotation_error, translation_error


def area_under_curve(errors: torch.Tensor, max_threshold: int) -> float:
    """Mean over thresholds 1, 2, ..., max_threshold degrees of the fraction of errors below."""
    thresholds = torch.arange(1, max_threshold + 1, dtype=errors.dtype)
    return float((errors[:, None] < thresholds).double().mean(dim=0).mean())


def summarise_pose_errors(rotation_error: torch.Tensor, translation_error: torch.Tensor) -> PoseAccuracy:
    """The summary of pair errors [P] (degrees), e.g. `relative_pose_errors` of several scenes
    concatenated."""
    if len(rotation_error) == 0:
        raise ValueError("pose accuracy needs at least one pair of views")
    if not (torch.isfinite(rotation_error).all() and torch.isfinite(translation_error).all()):
        raise ValueError("non-finite camera poses")
    return PoseAccuracy(
        pairs=len(rotation_error),
        rotation_error_median=float(rotation_error.median()),
        translation_error_median=float(translation_error.median()),
        rra_15=float((rotation_error < 15).double().mean()),
        rta_15=float((translation_error < 15).double().mean()),
        auc_30=area_under_curve(torch.maximum(rotation_error, translation_error), 30),
    )


def pose_accuracy(predicted: torch.Tensor, reference: torch.Tensor) -> PoseAccuracy:
    """The summary for extrinsics [V, 3, 4] (V >= 2)."""
    if predicted.shape[0] < 2:
        raise ValueError("pose accuracy needs at least two views")
    return summarise_pose_errors(*relative_pose_errors(predicted, reference))
