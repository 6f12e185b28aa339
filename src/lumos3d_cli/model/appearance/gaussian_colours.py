"""Colouring pixel Gaussians with the operator's output instead of regressed colours: the raw
SH channels of the Gaussian head's layout are overwritten with the restored pixel's colour as the
degree-0 coefficient and zero view dependence."""

from __future__ import annotations

import torch

from lumos3d_cli.io.gaussians import rgb_to_sh_dc, sh_coefficient_count
from lumos3d_cli.model.gaussian_adapter import SH_START


def with_operator_colours(params: torch.Tensor, colours: torch.Tensor, sh_degree: int) -> torch.Tensor:
    """params [B, V, H, W, C-1] raw Gaussian parameters (gaussian_adapter layout, confidence split
    off), colours [B, V, 3, H, W] restored sRGB in [0, 1] -> params with the SH block replaced:
    DC = the colour (the adapter's DC weight is 1), higher degrees 0. Differentiable in `colours`.

    The voxelizer averages raw parameters, so a fused Gaussian's colour is the confidence-weighted
    mean of its pixels' restored colours.
    """
    count = sh_coefficient_count(sh_degree)
    if params.shape[-1] != SH_START + 3 * count:
        raise ValueError(f"{params.shape[-1]} raw Gaussian channels, expected {SH_START + 3 * count} for SH degree {sh_degree}")
    dc = rgb_to_sh_dc(colours.to(params.dtype)).permute(0, 1, 3, 4, 2)  # [B, V, H, W, 3]
    sh = torch.zeros(*dc.shape[:-1], 3, count, dtype=params.dtype, device=params.device)
    sh = torch.cat((dc[..., None], sh[..., 1:]), dim=-1)  # colour-major: channel c's K coefficients together
    return torch.cat((params[..., :SH_START], sh.flatten(-2)), dim=-1)
