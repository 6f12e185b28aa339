"""Cross-illumination distillation (AnySplat's form): the student, seeing degraded images, is
pulled towards a frozen teacher that sees the normal-light images.

pose: Huber (delta 1) between the student's and the teacher's pose encodings at every
refinement iteration i of N, weighted 0.6^(N-i-1) and averaged over iterations;
depth: MSE between the student's *rendered* depth and the teacher's depth, on the pixels whose
teacher confidence is above that view's 30th percentile.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

ITERATION_DECAY = 0.6
CONFIDENCE_QUANTILE = 0.3


def iteration_weights(count: int) -> list[float]:
    """0.6^(N-i-1) for i = 0..N-1: the last refinement weighs 1."""
    return [ITERATION_DECAY ** (count - index - 1) for index in range(count)]


def weighted_pose_huber(predictions: list[torch.Tensor], targets: list[torch.Tensor]) -> torch.Tensor:
    """Mean over iterations of weight_i * Huber(prediction_i, target_i); encodings [B, V, 9]."""
    if len(predictions) != len(targets):
        raise ValueError(f"{len(predictions)} student refinements but {len(targets)} targets")
    weights = iteration_weights(len(predictions))
    total = sum(w * F.huber_loss(p, t.detach(), delta=1.0) for w, p, t in zip(weights, predictions, targets))
    return total / len(predictions)


def confidence_mask(confidence: torch.Tensor, quantile: float = CONFIDENCE_QUANTILE) -> torch.Tensor:
    """[B, V, H, W] confidence -> bool mask of pixels strictly above each view's quantile."""
    flat = confidence.detach().flatten(2).float()
    threshold = torch.quantile(flat, quantile, dim=-1, keepdim=True)
    return (flat > threshold).reshape(confidence.shape)


def depth_distillation(rendered_depth: torch.Tensor, teacher_depth: torch.Tensor, teacher_confidence: torch.Tensor) -> torch.Tensor:
    """MSE over confident pixels; all [B, V, H, W]. Zero when no pixel qualifies."""
    mask = confidence_mask(teacher_confidence)
    if not mask.any():
        return rendered_depth.sum() * 0.0
    return torch.mean((rendered_depth[mask] - teacher_depth.detach()[mask]) ** 2)
