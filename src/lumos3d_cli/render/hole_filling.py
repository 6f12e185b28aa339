"""Fill the parts of a rendered view that no Gaussian covers, instead of showing the background.

A scene built from photos covers only what they saw. Rendered at a photo's own camera it still
leaves thin gaps at the borders (rendered alpha below 1 between the splats of the only view
that saw them); rendered at a novel camera it can leave whole regions empty (buu's held-out
frame 19 has a wedge of its floor no other photo saw). Composited over black these read as dark
hatching and black wedges. Filling them makes the view a restoration of the whole photo:

- where the rendered alpha is at least OBSERVED_ALPHA, the colour is the rendered one divided by
  alpha (the splats' own colour, as if they covered the pixel);
- elsewhere the colour is extrapolated from the observed pixels around it by Navier-Stokes
  inpainting (OpenCV), computed at a longer side of at most FILL_SIDE px (the fill is smooth;
  this bounds its time on large photos);
- the result is the render plus (1 - alpha) times that colour, so fully covered pixels are
  unchanged and partly covered ones keep their splats' share.

Only the render itself is used: no photo, so a held-out view's own photo never leaks into it.
Test-time refinement fits `splat_colours` of its renders (refine.settings), so a fitted view's
covered pixels show exactly what was fitted.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.render.render import render

OBSERVED_ALPHA = 0.5  # rendered alpha at which a pixel's colour is trusted as the splats' own
FILL_SIDE = 512  # the longest side the inpainting runs at
INPAINT_RADIUS = 5  # px at the fill's resolution: the neighbourhood each filled pixel reads


@dataclass
class FilledView:
    """image [3, H, W] in [0, 1]; unobserved: the fraction of its pixels whose rendered alpha was
    below OBSERVED_ALPHA (filled by inpainting)."""

    image: torch.Tensor
    unobserved: float


def splat_colours(images: torch.Tensor, alphas: torch.Tensor) -> torch.Tensor:
    """images [..., 3, H, W] rendered over black, alphas [..., H, W] -> what a filled view shows
    where the alpha is at least OBSERVED_ALPHA: the render divided by its alpha (differentiable;
    lower alphas are divided by OBSERVED_ALPHA, as the fill paints those pixels instead)."""
    return images / alphas.clamp_min(OBSERVED_ALPHA).unsqueeze(-3)


def _inpaint(colour: np.ndarray, unobserved: np.ndarray) -> np.ndarray:
    """colour [H, W, 3] float32 (anything where unobserved), unobserved [H, W] bool -> the colour
    with the unobserved pixels extrapolated from the observed ones, [H, W, 3] float32."""
    height, width = unobserved.shape
    scale = min(1.0, FILL_SIDE / max(height, width))
    small_size = (max(1, round(width * scale)), max(1, round(height * scale)))
    full_colour = colour
    weight = (~unobserved).astype(np.float32)
    if scale < 1:
        # Downsample the observed colour as a weighted mean, so unobserved pixels do not darken it.
        summed = cv2.resize(colour * weight[..., None], small_size, interpolation=cv2.INTER_AREA)
        weight = cv2.resize(weight, small_size, interpolation=cv2.INTER_AREA)
        colour = summed / np.maximum(weight, 1e-6)[..., None]
    mask = (weight < 0.5).astype(np.uint8)
    # OpenCV's Navier-Stokes inpainting reads memory it never wrote on a one-row image (NaN or
    # different values run to run; a 3x2000 view shrinks to 1x512): thin images are inpainted
    # with their edge rows or columns repeated to three.
    pad_y, pad_x = int(mask.shape[0] < 3), int(mask.shape[1] < 3)
    colour = cv2.copyMakeBorder(colour, pad_y, pad_y, pad_x, pad_x, cv2.BORDER_REPLICATE)
    mask = cv2.copyMakeBorder(mask, pad_y, pad_y, pad_x, pad_x, cv2.BORDER_REPLICATE)
    filled = np.stack([cv2.inpaint(np.ascontiguousarray(colour[..., c]), mask, INPAINT_RADIUS, cv2.INPAINT_NS)
                       for c in range(3)], axis=-1)
    filled = filled[pad_y:filled.shape[0] - pad_y, pad_x:filled.shape[1] - pad_x]
    if scale < 1:
        filled = cv2.resize(filled, (width, height), interpolation=cv2.INTER_LINEAR)
    return np.where(unobserved[..., None], filled, full_colour)


def fill_unobserved(image: torch.Tensor, alpha: torch.Tensor) -> FilledView:
    """image [3, H, W] a render composited over black, alpha [H, W] its rendered alpha -> the view
    with its uncovered parts filled (module docstring), in the image's dtype and device. A view
    with no observed pixel has nothing to extrapolate from and is returned as it is."""
    require_finite("rendered image", image)
    require_finite("rendered alpha", alpha)
    image_cpu = image.detach().float().cpu()  # [3, H, W]
    alpha_cpu = alpha.detach().float().cpu().clamp(0, 1)  # [H, W]
    rendered = image_cpu.permute(1, 2, 0).numpy()  # [H, W, 3]
    coverage = alpha_cpu.numpy()
    unobserved = coverage < OBSERVED_ALPHA
    fraction = float(unobserved.mean())
    if unobserved.all():
        return FilledView(image, fraction)
    colour = np.where(unobserved[..., None], 0.0, splat_colours(image_cpu, alpha_cpu).permute(1, 2, 0).numpy())
    colour = colour.astype(np.float32)
    if unobserved.any():
        colour = _inpaint(colour, unobserved)
    result = np.clip(rendered + (1 - coverage)[..., None] * colour, 0, 1)
    filled = torch.from_numpy(np.ascontiguousarray(result.transpose(2, 0, 1)))
    return FilledView(filled.to(device=image.device, dtype=image.dtype), fraction)


def render_shown(gaussians: Gaussians, camera: Cameras, fill: bool, background: tuple[float, float, float] | None = None,
                 sh_degree: int | None = None, antialiased: bool = False) -> FilledView:
    """One camera's view [3, H, W] as it is shown: with `fill` the render completed by
    `fill_unobserved` (restore's views; `background` does not apply), else the render over
    `background`; with the fraction of its pixels below OBSERVED_ALPHA either way. No gradients."""
    with torch.no_grad():
        output = render(gaussians, camera, background=None if fill else background, sh_degree=sh_degree,
                        antialiased=antialiased)
    image, alpha = output.images[0], output.alphas[0]
    if fill:
        return fill_unobserved(image, alpha)
    return FilledView(image, float((alpha < OBSERVED_ALPHA).float().mean()))
