"""Voxel-level 3D consistency loss: features of renders and of normal-light images at 5 scales
are back-projected with the predicted geometry into one shared voxel grid per scale
(confidence-softmax fusion, as the model's voxelizer), and their per-channel mean and standard
deviation over voxels are matched: sum_i w_i (|mu_i - mu_hat_i|_1 + |sigma_i - sigma_hat_i|_1),
with sum_i w_i = 1.

Features: VGG-19 relu1_1 ... relu5_1 when VGG weights are configured, else an RGB pyramid
(average pooling by 1, 2, 4, 8, 16; at least one pixel). The voxel edge at scale i is voxel_size * 2^i times the
scene scale. The geometry (points, confidence) is detached: this term shapes appearance; the
geometry is the distillation's job.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from lumos3d_cli.losses.feature_networks import FeatureTrunk, imagenet_normalise
from lumos3d_cli.model.voxelize import voxelize

VGG_SCALES = ("relu1_1", "relu2_1", "relu3_1", "relu4_1", "relu5_1")
_STD_EPS = 1e-5


class VoxelStatisticsLoss(nn.Module):
    def __init__(self, trunk: FeatureTrunk | None = None, voxel_size: float = 0.002, weights: tuple[float, ...] = (1, 1, 1, 1, 1)):
        super().__init__()
        if len(weights) != len(VGG_SCALES) or min(weights) < 0 or sum(weights) <= 0:
            raise ValueError(f"voxel loss needs {len(VGG_SCALES)} non-negative scale weights, got {weights}")
        self.trunk = trunk.eval().requires_grad_(False) if trunk is not None else None
        self.voxel_size = voxel_size
        total = float(sum(weights))
        self.weights = [float(w) / total for w in weights]

    def _features(self, images: torch.Tensor) -> list[torch.Tensor]:
        if self.trunk is None:
            height, width = images.shape[-2:]
            return [
                F.adaptive_avg_pool2d(images, (max(1, height >> i), max(1, width >> i))) for i in range(len(VGG_SCALES))
            ]
        outputs = self.trunk(imagenet_normalise(images), list(VGG_SCALES))
        return [outputs[name] for name in VGG_SCALES]

    def forward(
        self, renders: torch.Tensor, targets: torch.Tensor, world_points: torch.Tensor, confidence: torch.Tensor,
        scene_scale: torch.Tensor,
    ) -> torch.Tensor:
        """renders, targets [B, V, 3, H, W]; world_points [B, V, H, W, 3]; confidence logits
        [B, V, H, W]; scene_scale [B]."""
        batch, views = renders.shape[:2]
        flat_renders = renders.reshape(batch * views, *renders.shape[2:])
        with torch.no_grad():
            target_features = self._features(targets.reshape(batch * views, *targets.shape[2:]))
        render_features = self._features(flat_renders)
        points = world_points.detach().reshape(batch * views, *world_points.shape[2:]).permute(0, 3, 1, 2)
        logits = confidence.detach().reshape(batch * views, 1, *confidence.shape[2:])
        total = renders.sum() * 0.0
        for scale, (weight, rendered, target) in enumerate(zip(self.weights, render_features, target_features)):
            if weight == 0:
                continue
            size = rendered.shape[-2:]
            scaled_points = F.interpolate(points, size=size, mode="area")
            scaled_logits = F.interpolate(logits, size=size, mode="area")
            channels = rendered.shape[1]
            per_scene = []
            for scene in range(batch):
                rows = slice(scene * views, (scene + 1) * views)
                xyz = scaled_points[rows].permute(0, 2, 3, 1).reshape(-1, 3)
                features = torch.cat([rendered[rows], target[rows]], dim=1).permute(0, 2, 3, 1).reshape(-1, 2 * channels)
                fused = voxelize(xyz, features, scaled_logits[rows].reshape(-1), self.voxel_size * 2**scale * scene_scale[scene].detach())
                ours, reference = fused.features[:, :channels], fused.features[:, channels:]
                mean_gap = torch.mean(torch.abs(ours.mean(dim=0) - reference.mean(dim=0)))
                std_gap = torch.mean(torch.abs(_std(ours) - _std(reference)))
                per_scene.append(mean_gap + std_gap)
            total = total + weight * torch.stack(per_scene).mean()
        return total


def _std(values: torch.Tensor) -> torch.Tensor:
    """Per-channel standard deviation over rows [M, C] -> [C], finite gradient at zero spread."""
    return torch.sqrt(values.var(dim=0, unbiased=False) + _STD_EPS)
