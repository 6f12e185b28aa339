"""The training objective of each stage, with every term reported separately.

teacher: L = w_rec MSE + w_lpips LPIPS + w_pose pose(GT) + w_depth sparse-depth(GT)
student: L = w_rec MSE + w_lpips LPIPS + omega_distill (w_pose pose + w_depth depth)
             + omega_lumos (0.1 content + 1.0 image + 0.01 voxel)
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import torch
from torch import nn

from lumos3d_cli.errors import InputError
from lumos3d_cli.losses.distillation import depth_distillation, weighted_pose_huber
from lumos3d_cli.losses.feature_networks import load_trunk
from lumos3d_cli.losses.loss_config import LossConfig
from lumos3d_cli.losses.lpips import LPIPS
from lumos3d_cli.losses.lumos.content import ContentLoss
from lumos3d_cli.losses.lumos.image import image_l1
from lumos3d_cli.losses.lumos.voxel import VoxelStatisticsLoss
from lumos3d_cli.losses.reconstruction import lpips_loss, mse_loss
from lumos3d_cli.losses.supervision import pose_supervision, sparse_depth_supervision
from lumos3d_cli.model.lumos3d import Lumos3DOutput

logger = logging.getLogger(__name__)


@dataclass
class StageBatch:
    """targets [B, V, 3, H, W] normal-light images; dataset geometry for the teacher stage:
    extrinsics [B, V, 3, 4], intrinsics [B, V, 3, 3], sparse_depth [B, V, H, W], has_poses [B]."""

    targets: torch.Tensor
    extrinsics: torch.Tensor | None = None
    intrinsics: torch.Tensor | None = None
    sparse_depth: torch.Tensor | None = None
    has_poses: torch.Tensor | None = None


class TrainingObjective(nn.Module):
    def __init__(self, config: LossConfig, stage: str):
        super().__init__()
        self.config = config
        self.stage = stage
        trunk = load_trunk("vgg19", config.vgg_weights) if config.vgg_weights else None
        uses_lumos = stage == "student" and config.lumos > 0
        if uses_lumos and config.content > 0 and trunk is None:
            logger.warning("loss.vgg_weights is not set: the content term of the Lumos loss is off "
                           "(give a torchvision vgg19 weight file to enable it)")
        self.content = ContentLoss(trunk) if (uses_lumos and config.content > 0 and trunk is not None) else None
        self.voxel = (
            VoxelStatisticsLoss(trunk, config.voxel_size, config.voxel_scale_weights)
            if uses_lumos and config.voxel > 0 else None
        )
        if uses_lumos and self.voxel is not None and trunk is None:
            logger.info("voxel loss uses an RGB pyramid (no VGG weights configured)")
        if config.lpips > 0:
            if not config.lpips_weights:
                raise InputError("loss.lpips > 0 needs loss.lpips_weights: a torchvision vgg16/alexnet weight file")
            self.lpips = LPIPS(config.lpips_network, config.lpips_weights)
        else:
            self.lpips = None

    def forward(
        self, output: Lumos3DOutput, renders: torch.Tensor, rendered_depth: torch.Tensor, batch: StageBatch,
        teacher: Lumos3DOutput | None = None,
    ) -> dict[str, torch.Tensor]:
        """Returns {'total': weighted sum, <term>: unweighted value, ...}."""
        c = self.config
        terms: dict[str, torch.Tensor] = {"mse": mse_loss(renders, batch.targets)}
        total = c.reconstruction * terms["mse"]
        if self.lpips is not None:
            terms["lpips"] = lpips_loss(self.lpips, renders, batch.targets)
            total = total + c.lpips * terms["lpips"]
        if self.stage == "teacher":
            size = tuple(output.depth.shape[-2:])
            terms["pose"] = pose_supervision(output.pose_enc_list, batch.extrinsics, batch.intrinsics, size, batch.has_poses)
            terms["depth"] = sparse_depth_supervision(output.depth, output.depth_conf, batch.sparse_depth)
            total = total + c.supervised_pose * terms["pose"] + c.supervised_depth * terms["depth"]
        else:
            if teacher is None:
                raise ValueError("the student stage needs the teacher's output")
            terms["distill_pose"] = weighted_pose_huber(output.pose_enc_list, teacher.pose_enc_list)
            terms["distill_depth"] = depth_distillation(rendered_depth, teacher.depth, teacher.depth_conf)
            distill = c.distill_pose * terms["distill_pose"] + c.distill_depth * terms["distill_depth"]
            terms["image"] = image_l1(renders, batch.targets)
            lumos = c.image * terms["image"]
            if self.content is not None:
                terms["content"] = self.content(renders, batch.targets)
                lumos = lumos + c.content * terms["content"]
            if self.voxel is not None:
                terms["voxel"] = self.voxel(renders, batch.targets, output.world_points, output.pixel_confidence, output.scene_scale)
                lumos = lumos + c.voxel * terms["voxel"]
            total = total + c.distill * distill + c.lumos * lumos
        terms["total"] = total
        return terms
