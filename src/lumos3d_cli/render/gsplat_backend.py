"""gsplat (CUDA) as the rasterizer for tensors on a GPU, with our conventions and settings."""

from __future__ import annotations

import importlib.util

import torch

from lumos3d_cli.io.cameras import Cameras, to_homogeneous
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.render.settings import RasterSettings


def gsplat_available() -> bool:
    return importlib.util.find_spec("gsplat") is not None


def render_with_gsplat(gaussians: Gaussians, cameras: Cameras, settings: RasterSettings, background: torch.Tensor):
    """Return images [V,3,H,W], alphas [V,H,W], expected depths [V,H,W], radii [V,N,2]."""
    import gsplat

    device, dtype = gaussians.means.device, gaussians.means.dtype
    viewmats = to_homogeneous(cameras.extrinsics).to(device=device, dtype=dtype)
    intrinsics = cameras.intrinsics.to(device=device, dtype=dtype)
    k = (settings.sh_degree + 1) ** 2
    colours, alphas, meta = gsplat.rasterization(
        gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities, gaussians.sh[:, :k, :],
        viewmats, intrinsics, settings.width, settings.height,
        near_plane=settings.near, far_plane=settings.far, eps2d=settings.eps2d, sh_degree=settings.sh_degree,
        packed=False, render_mode="RGB+ED", backgrounds=background.expand(len(cameras), 3),
        rasterize_mode="antialiased" if settings.antialiased else "classic",
    )
    radii = meta["radii"]
    if radii.dim() == 2:  # gsplat < 1.5 returns one radius per Gaussian
        radii = radii[..., None].expand(*radii.shape, 2)
    return colours[..., :3].permute(0, 3, 1, 2), alphas[..., 0], colours[..., 3], radii.to(torch.int32)
