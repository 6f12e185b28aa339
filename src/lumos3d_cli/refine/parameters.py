"""The Gaussians as unconstrained leaf tensors for the optimiser (3DGS's parameterisation) and
back: log scales, opacity logits, quaternions renormalised after each step, SH split into the
colour (DC) and the view-dependent bands, positions free, along rays, or fixed."""

from __future__ import annotations

import math

import torch

from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.refine.settings import Positions
from lumos3d_cli.rotations import unit_quaternions

# Scales are kept within these multiples of the scene's extent: below, a Gaussian is far under a
# pixel from any camera (its log would only drift); above, it covers the whole scene. Degenerate
# inputs (1e-6 or 1e3 world units) land on the bounds instead of producing huge or vanishing steps.
MIN_RELATIVE_SCALE = 1e-7
MAX_RELATIVE_SCALE = 1.0
# Opacities are kept in [OPACITY_BOUND, 1 - OPACITY_BOUND] so that their logits are finite.
OPACITY_BOUND = 1e-6


def scene_extent(means: torch.Tensor, centres: torch.Tensor) -> float:
    """The scene's size in world units, for positions' and cameras' learning rates: the median
    distance from the camera centres [V, 3] to the Gaussians' means [N, 3] (also defined for one
    camera, unlike the spread of the centres); 1 when there are no Gaussians."""
    if means.shape[0] == 0:
        return 1.0
    sample = means[torch.linspace(0, means.shape[0] - 1, min(means.shape[0], 4096)).long()].double()
    # The cameras stay on the CPU while the Gaussians may be on the GPU (refinement's working views).
    distance = torch.cdist(centres.to(sample), sample).median().item()
    return distance if math.isfinite(distance) and distance > 0 else 1.0


def _nearest_ray_directions(means: torch.Tensor, centres: torch.Tensor) -> torch.Tensor:
    """[N, 3] unit directions from each mean's nearest camera centre [V, 3] to it."""
    centres = centres.to(means)
    direction = means - centres[torch.cdist(means, centres).argmin(dim=1)]
    return direction / direction.norm(dim=-1, keepdim=True).clamp_min(1e-12)


class GaussianParameters:
    """Leaf tensors that define Gaussians [N]: `offsets` (positions: [N, 3] for "free", [N, 1]
    distances along the ray for "ray", none for "fixed"), `quats` [N, 4], `log_scales` [N, 3],
    `opacity_logits` [N], `colour` [N, 1, 3] (SH DC) and `sh_rest` [N, K-1, 3]."""

    def __init__(self, gaussians: Gaussians, positions: Positions, centres: torch.Tensor, extent: float):
        g = gaussians.detach()
        self.positions = positions
        self.origin = g.means.clone()
        self.directions = _nearest_ray_directions(g.means, centres) if positions == "ray" else None
        self.log_scale_bounds = (math.log(MIN_RELATIVE_SCALE * extent), math.log(MAX_RELATIVE_SCALE * extent))
        width = {"free": 3, "ray": 1, "fixed": 0}[positions]
        self.offsets = torch.zeros(len(g), width, dtype=g.means.dtype, device=g.means.device,
                                   requires_grad=positions != "fixed")
        self.quats = g.quats.clone().requires_grad_(True)
        # A zero scale or opacity gives an infinite log or logit here; normalise() bounds it.
        self.log_scales = torch.log(g.scales.clamp_min(0)).requires_grad_(True)
        self.opacity_logits = torch.logit(g.opacities.clamp(0, 1)).requires_grad_(True)
        self.colour = g.sh[:, :1].clone().requires_grad_(True)
        self.sh_rest = g.sh[:, 1:].clone().requires_grad_(True)
        self.normalise()

    def means(self) -> torch.Tensor:
        """[N, 3] current positions (differentiable in `offsets`)."""
        if self.positions == "free":
            return self.origin + self.offsets
        if self.positions == "ray":
            return self.origin + self.offsets * self.directions
        return self.origin

    def gaussians(self) -> Gaussians:
        """The activated Gaussians, differentiable in the leaves."""
        return Gaussians(
            self.means(), self.quats, torch.exp(self.log_scales), torch.sigmoid(self.opacity_logits),
            torch.cat([self.colour, self.sh_rest], dim=1),
        )

    @torch.no_grad()
    def normalise(self) -> None:
        """After a step: unit quaternions (a vanished one becomes the identity, as the
        rasterizer reads it), scales and opacities back inside their bounds."""
        self.quats.copy_(unit_quaternions(self.quats))
        self.log_scales.clamp_(*self.log_scale_bounds)
        bound = math.log(OPACITY_BOUND / (1 - OPACITY_BOUND))
        self.opacity_logits.clamp_(bound, -bound)
