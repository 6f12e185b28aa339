"""Load the CPU rasterizer's compiled kernels before the first render needs them.

numba keeps the kernels compiled on disk (cache=True), but loading them is the first call's work:
0.35 s on 2 cores (measured: the first weights render of a two-Gaussian scene 0.34 s, the second
1 ms). A restore pays that inside the budget stage unless a thread that has a core to spare
(`pipeline.module_prefetch`, during structure-from-motion) renders a tiny scene first, with the
dtypes and array layouts the pipeline uses: float32 Gaussians, the weights pass, and a forward
and backward pass.
"""

from __future__ import annotations

import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.render.render import render

_SIZE = 16  # pixels a side: one tile


def _tiny_scene() -> tuple[Gaussians, Cameras]:
    """Two float32 Gaussians in front of one 16x16 camera at the origin."""
    gaussians = Gaussians(
        means=torch.tensor([[0.0, 0.0, 2.0], [0.1, -0.1, 3.0]]),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.9, 0.1, 0.2, 0.0]]),
        scales=torch.full((2, 3), 0.2),
        opacities=torch.tensor([0.8, 0.6]),
        sh=torch.zeros(2, 1, 3),
    )
    intrinsics = torch.tensor([[[20.0, 0.0, _SIZE / 2], [0.0, 20.0, _SIZE / 2], [0.0, 0.0, 1.0]]])
    return gaussians, Cameras(torch.eye(4)[:3][None], intrinsics, [(_SIZE, _SIZE)])


def load_compiled_kernels() -> None:
    """Render the tiny scene with weights and once forward and backward (its result is dropped)."""
    gaussians, camera = _tiny_scene()
    render(gaussians, camera, weights=True)
    parameters = [gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities, gaussians.sh]
    for tensor in parameters:
        tensor.requires_grad_(True)
    torch.autograd.grad(render(gaussians, camera).images.sum(), parameters)
