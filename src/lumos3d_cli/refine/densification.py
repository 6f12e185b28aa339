"""Adaptive density control during refinement (3DGS's, for runs of tens to hundreds of steps):
the Gaussians whose image-space position gradient, averaged over the views that drew them, is
among the largest are where the views disagree with the scene, so they are split into two
smaller ones (3DGS's split: positions drawn from the Gaussian, scales / 1.6) or, when already
under a pixel, cloned; Gaussians that turned transparent are pruned. The optimiser's moments of
the Gaussians that stay are kept, the new ones start from zero (as 3DGS extends Adam's state).

3DGS selects by a fixed gradient threshold over 15,000 steps; a run here has a handful of
densifications, so each takes a fixed share of the Gaussians (the largest mean gradients), which
does not depend on the scene's scale or the images' resolution, and never more than the Gaussian
cap allows.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.refine.adam import FusedAdam
from lumos3d_cli.refine.parameters import GaussianParameters
from lumos3d_cli.refine.settings import DensifySettings
from lumos3d_cli.rotations import quaternion_to_matrix

# 3DGS's factor: the two halves of a split Gaussian are 1/1.6 of its size.
SPLIT_SCALE_DIVISOR = 1.6
# A Gaussian whose projected radius (3 sigma, in the working images' pixels) in the view that
# draws it largest is above this many pixels is split; at or below, it is cloned.
SPLIT_RADIUS_PX = 3.0


class GradientStatistics:
    """Per Gaussian since the last reset: the sum of the image-space gradient norms of its mean
    (d loss / d pixel) over the views that drew it, how many views drew it, and its largest
    projected radius (pixels)."""

    def __init__(self, count: int, device: torch.device):
        self.gradient_sum = torch.zeros(count, dtype=torch.float64, device=device)
        self.views = torch.zeros(count, dtype=torch.int64, device=device)
        self.largest_radius = torch.zeros(count, dtype=torch.float32, device=device)

    def add(self, world_gradient: torch.Tensor, means: torch.Tensor, radii: torch.Tensor, camera: Cameras) -> None:
        """world_gradient, means [N, 3]: d loss / d mean of one view's loss and the means it was
        rendered with; radii [N, 2] that view's projected radii (0: not drawn); camera: that view.
        A shift of the mean by d along the camera's x axis moves its pixel by fx d / z, so
        d loss / d u = (d loss / d x) z / fx (and likewise for v). With refined cameras the view's
        correction (a small rigid motion) is left out: an approximation for choosing Gaussians."""
        rotation = camera.extrinsics[0, :, :3].to(means)
        translation = camera.extrinsics[0, :, 3].to(means)
        gradient = world_gradient.detach() @ rotation.T
        depth = (means.detach() @ rotation.T + translation)[:, 2].clamp_min(1e-12)
        fx, fy = camera.intrinsics[0, 0, 0].to(means), camera.intrinsics[0, 1, 1].to(means)
        image_gradient = torch.hypot(gradient[:, 0] * depth / fx, gradient[:, 1] * depth / fy)
        drawn = (radii > 0).any(dim=-1) & torch.isfinite(image_gradient)
        self.gradient_sum += torch.where(drawn, image_gradient, torch.zeros_like(image_gradient)).double()
        self.views += drawn.long()
        self.largest_radius = torch.maximum(self.largest_radius, radii.amax(dim=-1).float())

    def mean_gradient(self) -> torch.Tensor:
        """[N] the mean over the views that drew each Gaussian (0 where none did)."""
        return torch.where(self.views > 0, self.gradient_sum / self.views.clamp_min(1), torch.zeros_like(self.gradient_sum))


@dataclass(frozen=True)
class DensificationStep:
    """What one densification did: Gaussians split, cloned and pruned, and how many there are now."""

    split: int
    cloned: int
    pruned: int
    gaussians: int


def _chosen(statistics: GradientStatistics, alive: torch.Tensor, settings: DensifySettings, room: int) -> torch.Tensor:
    """[N] bool: the alive Gaussians with the largest mean gradient, at most `fraction` of them and `room`."""
    eligible = alive & (statistics.views > 0)
    count = min(int(settings.fraction * int(alive.sum())), int(eligible.sum()), max(room, 0))
    chosen = torch.zeros_like(alive)
    if count > 0:
        score = torch.where(eligible, statistics.mean_gradient(), torch.full_like(statistics.gradient_sum, -1.0))
        chosen[torch.topk(score, count).indices] = True
    return chosen


def densify(parameters: GaussianParameters, optimizer: FusedAdam | torch.optim.Optimizer, statistics: GradientStatistics,
            settings: DensifySettings, generator: torch.Generator) -> DensificationStep:
    """Prune, split and clone in place: `parameters`' leaves and the `optimizer`'s parameters
    and moments are replaced by the new set (the survivors first, in their order, then the
    clones, then the split halves). Nothing is added past `settings.max_gaussians` (a scene
    already above it is not cut: the Gaussian budget does that); a scene whose every Gaussian
    turned transparent is not emptied. Needs free positions (`parameters.positions == "free"`)."""
    if parameters.positions != "free":
        raise ValueError(f"densification moves Gaussians freely; positions={parameters.positions!r}")
    with torch.no_grad():
        alive = torch.sigmoid(parameters.opacity_logits) >= settings.prune_opacity
        if not bool(alive.any()):
            alive = torch.ones_like(alive)
        pruned = int((~alive).sum())
        room = (settings.max_gaussians - int(alive.sum())) if settings.max_gaussians is not None else len(alive)
        chosen = _chosen(statistics, alive, settings, room)
        split = chosen & (statistics.largest_radius > SPLIT_RADIUS_PX)
        cloned = chosen & ~split
        keep = alive & ~split
        split_index = torch.nonzero(split).flatten()
        rows = torch.cat([torch.nonzero(keep).flatten(), torch.nonzero(cloned).flatten(), split_index, split_index])
        fresh = torch.zeros(len(rows), dtype=torch.bool, device=rows.device)
        fresh[int(keep.sum()):] = True
        means = parameters.means().detach()[rows]
        log_scales = parameters.log_scales.detach()[rows]
        if len(split_index):
            halves = slice(len(rows) - 2 * len(split_index), len(rows))
            scales = torch.exp(log_scales[halves])
            rotation = quaternion_to_matrix(parameters.quats.detach()[rows[halves]])
            noise = torch.randn(scales.shape, generator=generator, dtype=torch.float64).to(scales)
            means[halves] = means[halves] + (rotation @ (noise * scales)[..., None])[..., 0]
            log_scales[halves] = log_scales[halves] - torch.log(torch.tensor(SPLIT_SCALE_DIVISOR, dtype=log_scales.dtype))
        _replace_rows(parameters, optimizer, rows, fresh, means, log_scales)
    return DensificationStep(int(split.sum()), int(cloned.sum()), pruned, len(rows))


def _replace_rows(parameters: GaussianParameters, optimizer: FusedAdam | torch.optim.Optimizer, rows: torch.Tensor,
                  fresh: torch.Tensor, means: torch.Tensor, log_scales: torch.Tensor) -> None:
    """New leaves made of `rows` of the old ones (positions and log scales given), swapped into
    the optimiser with their moments gathered too (zero where `fresh`)."""
    parameters.origin = means
    replacements = {
        "offsets": torch.zeros_like(means), "quats": parameters.quats.detach()[rows],
        "log_scales": log_scales, "opacity_logits": parameters.opacity_logits.detach()[rows],
        "colour": parameters.colour.detach()[rows], "sh_rest": parameters.sh_rest.detach()[rows],
    }
    for name, values in replacements.items():
        old = getattr(parameters, name)
        new = values.clone().requires_grad_(old.requires_grad)
        for group in optimizer.param_groups:
            group["params"] = [new if p is old else p for p in group["params"]]
        state = optimizer.state.pop(old, None)
        if state is not None:
            mask = fresh.reshape(-1, *([1] * (new.dim() - 1)))
            optimizer.state[new] = {
                key: (torch.where(mask, torch.zeros_like(value[rows]), value[rows]) if torch.is_tensor(value) and value.dim()
                      else value)
                for key, value in state.items()
            }
        setattr(parameters, name, new)
