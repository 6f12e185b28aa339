"""Raw Gaussian-head channels -> activated Gaussians (AnySplat's adapter).

Per-pixel channel layout (K = (d+1)^2 SH coefficients per colour):
  0            opacity logit
  1..3         scale, raw (before softplus)
  4..7         rotation quaternion, raw, **xyzw** (reordered to the project's wxyz here)
  8..8+3K-1    SH coefficients, colour-major (channel 8 + c*K + k)
  last         fusion confidence logit (voxelizer softmax weight; not a Gaussian attribute)
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from lumos3d_cli.io.gaussians import Gaussians, sh_coefficient_count
from lumos3d_cli.model.architectures import Architecture
from lumos3d_cli.model.pose_encoding import normalize_quaternion, xyzw_to_wxyz

OPACITY = 0
SCALE = slice(1, 4)
ROTATION = slice(4, 8)
SH_START = 8


def sh_degree_weights(degree: int, dtype=torch.float32, device=None) -> torch.Tensor:
    """[K] multipliers of the raw SH outputs: 1 for the colour (DC) term, 0.1 * 0.25^l for degree
    l, so that view-dependent terms start small and the head learns colour first."""
    weights = [1.0] + [0.1 * 0.25**level for level in range(1, degree + 1) for _ in range(2 * level + 1)]
    return torch.tensor(weights, dtype=dtype, device=device)


def split_confidence(raw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """raw [..., C] -> (Gaussian parameters [..., C-1], confidence logit [...])."""
    return raw[..., :-1], raw[..., -1]


def activate_gaussians(means: torch.Tensor, params: torch.Tensor, scene_scale: torch.Tensor, architecture: Architecture) -> Gaussians:
    """means [N, 3], raw parameters [N, C-1] (layout above, without the confidence), scene scale
    (scalar tensor, world units) -> Gaussians.

    opacity = sigmoid(logit); scale = scene_scale * clamp(base * softplus(raw), min, max) with the
    architecture's relative base/min/max; quaternion normalised (a zero quaternion becomes the identity);
    SH scaled per degree.
    """
    k = sh_coefficient_count(architecture.sh_degree)
    expected = SH_START + 3 * k
    if params.shape[-1] != expected:
        raise ValueError(f"{params.shape[-1]} raw Gaussian channels, expected {expected} for SH degree {architecture.sh_degree}")
    relative_scale = (architecture.gaussian_scale_base * F.softplus(params[:, SCALE])).clamp(
        architecture.gaussian_scale_min, architecture.gaussian_scale_max
    )
    sh = params[:, SH_START:].reshape(-1, 3, k).transpose(1, 2)  # [N, K, 3]
    return Gaussians(
        means=means,
        quats=xyzw_to_wxyz(normalize_quaternion(params[:, ROTATION], identity_first=False)),
        scales=relative_scale * scene_scale,
        opacities=torch.sigmoid(params[:, OPACITY]),
        # contiguous: the product keeps the transposed layout, and every render of the scene
        # (budget, refinement, views) copied it again (0.6 s of a 25-view budget)
        sh=(sh * sh_degree_weights(architecture.sh_degree, sh.dtype, sh.device)[None, :, None]).contiguous(),
    )


def shrink_raw_scales(params: torch.Tensor, factor: float) -> torch.Tensor:
    """raw parameters [..., C] -> the same with every Gaussian's scale divided by `factor` >= 1
    (before the architecture's clamp): softplus(raw') = softplus(raw) / factor. For a grid of
    pixel Gaussians made `factor` times denser, whose pixels are that much smaller."""
    if factor < 1:
        raise ValueError(f"factor {factor} must be >= 1")
    shrunk = params.clone()
    target = (F.softplus(params[..., SCALE]) / factor).clamp_min(torch.finfo(params.dtype).tiny)
    # softplus^-1(y) = y + log(1 - exp(-y)), stable for small and large y
    shrunk[..., SCALE] = target + torch.log(-torch.expm1(-target))
    return shrunk
