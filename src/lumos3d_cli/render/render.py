"""Render Gaussians from cameras: `render(gaussians, cameras)` picks the backend, checks inputs,
composites the background and normalises depth."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Literal

import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import MAX_SH_DEGREE, Gaussians
from lumos3d_cli.render.constants import EPS2D, FAR_PLANE, MAX_IMAGE_SIDE, NEAR_PLANE
from lumos3d_cli.render.gsplat_backend import gsplat_available, render_with_gsplat
from lumos3d_cli.render.rasterizer import RasterizeGaussians, rasterize_with_weights
from lumos3d_cli.render.reference import rasterize_reference, rasterize_with_weights_reference
from lumos3d_cli.render.settings import RasterSettings

logger = logging.getLogger(__name__)

Backend = Literal["auto", "cpu", "reference", "gsplat"]


@dataclass
class RenderOutput:
    """images [V,3,H,W] with the background composited; alphas [V,H,W]; depths [V,H,W] expected
    camera-space depth (0 where nothing was hit); radii [V,N,2] int32 (0: not drawn); weights
    [V,N] each Gaussian's rendered weight, the sum over the view's pixels of alpha x
    transmittance (only when asked for)."""

    images: torch.Tensor
    alphas: torch.Tensor
    depths: torch.Tensor
    radii: torch.Tensor
    weights: torch.Tensor | None = None

    @property
    def visible(self) -> torch.Tensor:
        """[V, N] bool: the Gaussian was drawn in that view."""
        return (self.radii > 0).any(dim=-1)


def _check_inputs(gaussians: Gaussians, cameras: Cameras, sh_degree: int) -> tuple[int, int]:
    gaussians.require_finite("gaussians")
    gaussians.require_activated("gaussians")
    require_finite("cameras.extrinsics", cameras.extrinsics)
    require_finite("cameras.intrinsics", cameras.intrinsics)
    if not 0 <= sh_degree <= min(gaussians.sh_degree, MAX_SH_DEGREE):
        raise ValueError(f"sh_degree {sh_degree} must be between 0 and the scene's degree {gaussians.sh_degree}")
    if len(cameras) == 0:
        raise ValueError("cameras: no camera to render from")
    focal = cameras.intrinsics[:, [0, 1], [0, 1]]
    if bool((focal <= 0).any()):
        raise ValueError(f"cameras.intrinsics: the focal lengths must be positive, got {focal[(focal <= 0).any(dim=1)][0].tolist()}")
    if len(set(cameras.sizes)) != 1:
        raise ValueError(f"cameras have different image sizes {sorted(set(cameras.sizes))}; use Cameras.rescaled")
    width, height = cameras.sizes[0]
    if not (1 <= width <= MAX_IMAGE_SIDE and 1 <= height <= MAX_IMAGE_SIDE):
        raise InputError(f"cameras: images of {width}x{height} pixels; render at 1 to {MAX_IMAGE_SIDE} pixels a side "
                         "(Cameras.rescaled)")
    return cameras.sizes[0]


def _render_cpu(gaussians, cameras, settings, background, use_reference: bool, weights: bool):
    device = gaussians.means.device
    g = gaussians.to(device="cpu")
    images, alphas, depths, radii, per_view_weights = [], [], [], [], []
    if weights:
        rasterize = rasterize_with_weights_reference if use_reference else rasterize_with_weights
    else:
        rasterize = rasterize_reference if use_reference else RasterizeGaussians.apply
    for index in range(len(cameras)):
        viewmat = cameras.extrinsics[index].detach().to(device="cpu", dtype=torch.float64)
        k = cameras.intrinsics[index].detach().double()
        intrinsics = (k[0, 0].item(), k[1, 1].item(), k[0, 2].item(), k[1, 2].item())
        colour, alpha, depth, radius, *weight = rasterize(
            g.means, g.quats, g.scales, g.opacities, g.sh, viewmat, intrinsics, settings
        )
        images.append(colour + (1 - alpha)[..., None] * background.to(colour))
        alphas.append(alpha)
        depths.append(depth / alpha.clamp_min(1e-10))
        radii.append(radius)
        per_view_weights += weight
    return RenderOutput(
        torch.stack(images).permute(0, 3, 1, 2).to(device), torch.stack(alphas).to(device),
        torch.stack(depths).to(device), torch.stack(radii).to(device),
        torch.stack(per_view_weights).to(device) if weights else None,
    )


def render(
    gaussians: Gaussians,
    cameras: Cameras,
    *,
    background: torch.Tensor | tuple[float, float, float] | None = None,
    sh_degree: int | None = None,
    antialiased: bool = False,
    near: float = NEAR_PLANE,
    far: float = FAR_PLANE,
    eps2d: float = EPS2D,
    backend: Backend = "auto",
    weights: bool = False,
) -> RenderOutput:
    """Render every camera (all of the same image size, taken from `cameras.sizes`) over
    `background` [3] (an RGB colour in [0, 1]; black when None). Float32 or float64 Gaussians
    render in their type; float16 and bfloat16 ones in float32.

    backend: "auto" = our CPU kernel for CPU tensors, gsplat for CUDA tensors when it imports
    (else our kernel on the CPU, with a warning); "cpu", "gsplat" or "reference" (the dense twin)
    force one. Differentiable w.r.t. every Gaussian tensor and the background, except with
    `weights`: then the render also returns each Gaussian's rendered weight per view
    (RenderOutput.weights; the CPU kernel and the twin in a forward-only pass that carries no
    gradients, gsplat through its backward).
    """
    degree = gaussians.sh_degree if sh_degree is None else sh_degree
    width, height = _check_inputs(gaussians, cameras, degree)
    settings = RasterSettings(width, height, min(degree, MAX_SH_DEGREE), near, far, eps2d, antialiased)
    if not all(tensor.dtype.is_floating_point for tensor in gaussians.tensors().values()):
        kinds = sorted({str(tensor.dtype) for tensor in gaussians.tensors().values()})
        raise ValueError(f"Gaussians of dtype {', '.join(kinds)}: give floating-point tensors")
    if gaussians.means.dtype in (torch.float16, torch.bfloat16):
        # the kernels blend in float32 or float64: half-precision Gaussians (e.g. from an autocast
        # training step) render in float32, and their gradients flow back through the cast
        gaussians = gaussians.to(dtype=torch.float32)
    dtype, device = gaussians.means.dtype, gaussians.means.device
    background = torch.zeros(3) if background is None else torch.as_tensor(background)
    if background.shape != (3,):
        raise ValueError(f"background must be one RGB colour [3], got shape {tuple(background.shape)}")
    background = background.to(device=device, dtype=dtype)
    require_finite("background", background)
    if bool(((background < 0) | (background > 1)).any()):
        raise ValueError(f"background {background.tolist()}: an RGB colour in [0, 1]")
    if backend == "auto":
        if device.type == "cuda":
            if gsplat_available():
                backend = "gsplat"
            else:
                logger.warning("gsplat is not installed: rendering on the CPU (install gsplat for CUDA rendering)")
                backend = "cpu"
        else:
            backend = "cpu"
    if backend == "gsplat":
        if not gsplat_available():  # was a bare ModuleNotFoundError
            raise ValueError("backend 'gsplat': gsplat is not installed (docs/performance.md, GPU); use backend 'auto' "
                             "or 'cpu'")
        return RenderOutput(*render_with_gsplat(gaussians, cameras, settings, background, weights))
    if backend not in ("cpu", "reference"):
        raise ValueError(f"unknown backend {backend!r}")
    return _render_cpu(gaussians, cameras, settings, background, backend == "reference", weights)
