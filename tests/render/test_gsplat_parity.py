"""Parity with gsplat (CUDA), the rasterizer whose conventions and constants ours pins: the same
scene projected by `gsplat.fully_fused_projection` and by our kernel, then rasterized by
`gsplat.rasterization` and by RasterizeGaussians, values and gradients.

Skips where gsplat or a CUDA device is missing, and for gsplat before 1.5 (no `opacities`
argument for the opacity-aware radius, one radius per Gaussian). Opacities stay below 0.95, so the
alpha cap (0.999 in gsplat before 2026, 0.99 since and here) is never reached."""

import inspect

import pytest
import torch

from lumos3d_cli.io.cameras import make_intrinsics, to_homogeneous
from lumos3d_cli.render.rasterizer import RasterizeGaussians, project
from lumos3d_cli.render.settings import RasterSettings
from lumos3d_cli.rotations import quaternion_to_matrix

from factories import random_scene

gsplat = pytest.importorskip("gsplat")
pytestmark = [
    pytest.mark.cuda,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="gsplat's kernels need a CUDA device"),
    pytest.mark.skipif(
        "opacities" not in inspect.signature(gsplat.fully_fused_projection).parameters,
        reason="gsplat < 1.5: no opacity-aware radius",
    ),
]

WIDTH, HEIGHT = 64, 48
INTRINSICS = (55.0, 53.0, 31.0, 25.0)
EPS2D = 0.3


def _scene(seed: int):
    """300 float32 Gaussians (SH degree 3) in front of a rotated camera, some beyond the image
    border; viewmat [3,4] float64 world->camera."""
    gaussians = random_scene(300, seed, degree=3, dtype=torch.float32, spread=1.2, depth=4.0)
    g = torch.Generator().manual_seed(seed)
    rotation = quaternion_to_matrix(torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64) + 0.2 * torch.randn(4, generator=g, dtype=torch.float64))
    viewmat = torch.cat([rotation, torch.randn(3, 1, generator=g, dtype=torch.float64) * 0.3], dim=1)
    camera_points = gaussians.means.double()
    gaussians.means = ((camera_points - viewmat[:, 3]) @ viewmat[:, :3]).float()
    return gaussians, viewmat


def _gsplat_camera(viewmat: torch.Tensor):
    """gsplat's camera arguments: viewmats [1,4,4] and Ks [1,3,3], float32 on the GPU."""
    ks = make_intrinsics(*INTRINSICS)
    return to_homogeneous(viewmat)[None].float().cuda(), ks.float().cuda()


@pytest.mark.parametrize("antialiased", [False, True])
def test_projection_matches_gsplat(antialiased):
    gaussians, viewmat = _scene(0)
    settings = RasterSettings(WIDTH, HEIGHT, 3, eps2d=EPS2D, antialiased=antialiased)
    means2d, conics, depths, opacities, _, radii = (
        torch.from_numpy(a) for a in project(*gaussians.tensors().values(), viewmat, INTRINSICS, settings)
    )
    viewmats, ks = _gsplat_camera(viewmat)
    g_radii, g_means2d, g_depths, g_conics, g_compensations = gsplat.fully_fused_projection(
        gaussians.means.cuda(), None, gaussians.quats.cuda(), gaussians.scales.cuda(), viewmats, ks, WIDTH, HEIGHT,
        eps2d=EPS2D, near_plane=settings.near, far_plane=settings.far, packed=False,
        calc_compensations=antialiased, opacities=gaussians.opacities.cuda(),
    )
    g_radii, g_means2d, g_depths, g_conics = (t[0].cpu() for t in (g_radii, g_means2d, g_depths, g_conics))
    ours_drawn, theirs_drawn = (radii > 0).any(-1), (g_radii > 0).any(-1)
    assert ours_drawn.sum() > 150
    assert (ours_drawn != theirs_drawn).sum() <= 3  # float32 rounding at the border of a cull test
    both = ours_drawn & theirs_drawn
    torch.testing.assert_close(radii[both], g_radii[both], rtol=0, atol=1)  # ceil of a float32 value
    torch.testing.assert_close(means2d[both], g_means2d[both], rtol=1e-4, atol=1e-3)
    torch.testing.assert_close(depths[both], g_depths[both], rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(conics[both], g_conics[both], rtol=1e-3, atol=1e-4)
    expected_opacities = gaussians.opacities
    if antialiased:
        expected_opacities = expected_opacities * g_compensations[0].cpu()
    torch.testing.assert_close(opacities[both], expected_opacities[both], rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("antialiased", [False, True])
def test_rasterization_and_gradients_match_gsplat(antialiased):
    gaussians, viewmat = _scene(1)
    settings = RasterSettings(WIDTH, HEIGHT, 3, eps2d=EPS2D, antialiased=antialiased)
    weights = [torch.randn(HEIGHT, WIDTH, 3), torch.randn(HEIGHT, WIDTH), torch.randn(HEIGHT, WIDTH)]

    leaves = [t.clone().requires_grad_(True) for t in gaussians.tensors().values()]
    colour, alpha, depth, _ = RasterizeGaussians.apply(*leaves, viewmat, INTRINSICS, settings)
    ours = torch.autograd.grad(sum((o * w).sum() for o, w in zip((colour, alpha, depth), weights)), leaves)

    cuda_leaves = [t.cuda().requires_grad_(True) for t in gaussians.tensors().values()]
    viewmats, ks = _gsplat_camera(viewmat)
    # "RGB+D": colour and the accumulated (not normalised) depth sum(w z), like RasterizeGaussians.
    renders, alphas, _ = gsplat.rasterization(
        *cuda_leaves, viewmats, ks, WIDTH, HEIGHT, near_plane=settings.near, far_plane=settings.far, eps2d=EPS2D,
        sh_degree=3, packed=False, render_mode="RGB+D", rasterize_mode="antialiased" if antialiased else "classic",
    )
    g_colour, g_depth, g_alpha = renders[0, ..., :3], renders[0, ..., 3], alphas[0, ..., 0]
    g_loss = sum((o * w.cuda()).sum() for o, w in zip((g_colour, g_alpha, g_depth), weights))
    theirs = [t.cpu() for t in torch.autograd.grad(g_loss, cuda_leaves)]

    assert alpha.mean() > 0.3
    for name, a, b in (("colour", colour, g_colour), ("alpha", alpha, g_alpha), ("depth", depth, g_depth)):
        difference = (a.detach() - b.detach().cpu()).abs()
        # An entry at the 1/255 alpha threshold may flip between float32 implementations.
        assert difference.mean() < 1e-4 * max(1.0, b.abs().max().item()), name
        assert difference.max() < 2e-2 * max(1.0, b.abs().max().item()), name
    for name, a, b in zip(gaussians.tensors(), ours, theirs):
        cosine = torch.nn.functional.cosine_similarity(a.flatten().double(), b.flatten().double(), dim=0)
        relative = (a - b).norm() / b.norm()
        assert cosine > 0.999 and relative < 2e-2, f"{name}: cosine {cosine:.5f}, relative L2 error {relative:.2e}"


def test_gsplat_weights_equal_the_cpu_kernels():
    """render(weights=True) on CUDA takes each Gaussian's weight from gsplat's backward
    (render/gsplat_backend.py); the CPU kernel counts the same sums in its forward pass."""
    from lumos3d_cli.io.cameras import Cameras
    from lumos3d_cli.render.render import render

    gaussians, viewmat = _scene(3)
    cameras = Cameras(viewmat[None], make_intrinsics(*INTRINSICS), [(WIDTH, HEIGHT)])
    cpu = render(gaussians, cameras, weights=True, eps2d=EPS2D).weights
    gpu = render(gaussians.to(device="cuda"), cameras, weights=True, eps2d=EPS2D, backend="gsplat").weights
    # float32 sums over a few hundred pixels of one view: 1e-3 px absolute, 1e-3 relative
    torch.testing.assert_close(gpu.cpu().to(cpu.dtype), cpu, atol=1e-3, rtol=1e-3)
