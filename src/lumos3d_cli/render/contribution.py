"""How much each Gaussian shows in a set of views: its rendered weight, the sum over every
pixel of every view of alpha x transmittance (the share of the pixel's colour it supplies).

A Gaussian that no view draws (outside every image, behind every camera, or with an alpha
under the threshold everywhere) has weight 0; one hidden behind opaque surfaces has a weight near
0: either can go without changing any render much.
The weights of one view sum to its total alpha, so they are in pixels: a weight of 0.5 is half
a pixel's colour, spread over the views.
"""

from __future__ import annotations

import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.render.render import render
from lumos3d_cli.render.view_threads import map_views


def rendered_weights(gaussians: Gaussians, cameras: Cameras, resolution: float = 1.0,
                     at_least_pixels: int = 0) -> torch.Tensor:
    """[N] each Gaussian's rendered weight summed over `cameras`, in pixels of the cameras' own
    images, on the Gaussians' device. `resolution` < 1 renders smaller images (faster) and scales
    the weights back by the pixel area, so the result estimates the full-resolution weight. A view
    of fewer than `at_least_pixels` pixels counts in pixels of an image of that many (its weights
    scaled up by the ratio): a 64x48 photo under the network's 224x168 grid shows each pixel
    Gaussian at a twelfth of a pixel. On the CPU the views render one per thread
    (`render.view_threads`)."""
    if not 0 < resolution <= 1:
        raise ValueError(f"resolution {resolution} must be in (0, 1]")
    device = gaussians.means.device

    def view_weights(index: int) -> torch.Tensor:
        camera = cameras[index]
        width, height = camera.sizes[0]
        small = (max(1, round(width * resolution)), max(1, round(height * resolution)))
        if small != (width, height):
            camera = camera.rescaled(*small)
        # Weights do not depend on colour: degree 0 skips the view-dependent SH terms. The
        # backend follows the Gaussians' device (the CPU kernel, or gsplat on CUDA).
        output = render(gaussians, camera, sh_degree=0, weights=True)
        return output.weights[0].double() * max(width * height, at_least_pixels) / (small[0] * small[1])

    total = torch.zeros(len(gaussians), dtype=torch.float64, device=device)
    for weights in map_views(view_weights, len(cameras), device):  # summed in view order: deterministic
        total += weights
    return total
