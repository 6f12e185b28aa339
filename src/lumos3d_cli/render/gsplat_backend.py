"""gsplat (CUDA) as the rasterizer for tensors on a GPU, with our conventions and settings."""

from __future__ import annotations

import contextlib
import functools
import importlib
import importlib.util
import sys
from types import ModuleType

import torch

from lumos3d_cli.io.cameras import Cameras, to_homogeneous
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.render.settings import RasterSettings


def gsplat_available() -> bool:
    return importlib.util.find_spec("gsplat") is not None


@functools.cache
def _loaded_gsplat() -> ModuleType:
    """gsplat with its CUDA extension loaded. The first load on a machine builds the extension (a
    minute) and prints its progress with rich on standard output, where `--json` writes its
    document (a first `restore --device cuda --json` wrote unreadable JSON): sent to stderr."""
    with contextlib.redirect_stdout(sys.stderr):
        gsplat = importlib.import_module("gsplat")
        with contextlib.suppress(ImportError):  # where a later gsplat moves it, the first call loads it
            importlib.import_module("gsplat.cuda._backend")
    return gsplat


def render_with_gsplat(gaussians: Gaussians, cameras: Cameras, settings: RasterSettings, background: torch.Tensor,
                       weights: bool = False):
    """Return images [V,3,H,W], alphas [V,H,W], expected depths [V,H,W], radii [V,N,2] and, with
    `weights`, each Gaussian's rendered weight per view [V,N] (else None)."""
    gsplat = _loaded_gsplat()

    device, dtype = gaussians.means.device, gaussians.means.dtype
    viewmats = to_homogeneous(cameras.extrinsics).to(device=device, dtype=dtype)
    intrinsics = cameras.intrinsics.to(device=device, dtype=dtype)
    k = (settings.sh_degree + 1) ** 2
    shared = {"near_plane": settings.near, "far_plane": settings.far, "eps2d": settings.eps2d, "packed": False,
              "rasterize_mode": "antialiased" if settings.antialiased else "classic"}
    colours, alphas, meta = gsplat.rasterization(
        gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities, gaussians.sh[:, :k, :],
        viewmats, intrinsics, settings.width, settings.height, sh_degree=settings.sh_degree,
        render_mode="RGB+ED", backgrounds=background.expand(len(cameras), 3), **shared,
    )
    radii = meta["radii"]
    if radii.dim() == 2:  # gsplat < 1.5 returns one radius per Gaussian
        radii = radii[..., None].expand(*radii.shape, 2)
    per_view_weights = _weights(gsplat, gaussians, viewmats, intrinsics, settings, shared) if weights else None
    return colours[..., :3].permute(0, 3, 1, 2), alphas[..., 0], colours[..., 3], radii.to(torch.int32), per_view_weights


def _weights(gsplat, gaussians: Gaussians, viewmats: torch.Tensor, intrinsics: torch.Tensor, settings: RasterSettings,
             shared: dict) -> torch.Tensor:
    """[V, N] the sum over each view's pixels of alpha x transmittance of every Gaussian: the
    gradient of the summed image with respect to a per-view scalar colour of 1 per Gaussian (a
    pixel's value is sum_i c_i alpha_i T_i, so d/dc_i of its sum is the weight). gsplat renders
    and differentiates that on the GPU; the CPU kernel counts the same sums directly."""
    ones = torch.ones(len(viewmats), len(gaussians), 1, device=viewmats.device, dtype=viewmats.dtype, requires_grad=True)
    g = gaussians.detach()
    with torch.enable_grad():
        image, _, _ = gsplat.rasterization(g.means, g.quats, g.scales, g.opacities, ones, viewmats, intrinsics,
                                           settings.width, settings.height, sh_degree=None, render_mode="RGB", **shared)
        (gradient,) = torch.autograd.grad(image.sum(), ones)
    return gradient[..., 0]
