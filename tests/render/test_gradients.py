"""The hand-written backward against finite differences (gradcheck) and the autograd twin."""

import pytest
import torch

from lumos3d_cli.render.rasterizer import RasterizeGaussians
from lumos3d_cli.render.reference import rasterize_reference
from lumos3d_cli.render.settings import RasterSettings

from factories import camera_at_origin, random_scene

VIEW = torch.eye(4, dtype=torch.float64)[:3]


def _inputs(gaussians):
    return [t.clone().requires_grad_(True) for t in gaussians.tensors().values()]


def _run_gradcheck(gaussians, settings, intrinsics):
    inputs = _inputs(gaussians)
    function = lambda *x: RasterizeGaussians.apply(*x, VIEW, intrinsics, settings)[:3]  # noqa: E731
    assert torch.autograd.gradcheck(function, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("antialiased", [False, True])
def test_gradcheck_overlapping_gaussians(seed, antialiased):
    gaussians = random_scene(10, seed, degree=2, spread=0.4)
    _run_gradcheck(gaussians, RasterSettings(24, 18, 2, antialiased=antialiased), (22.0, 22.0, 12.0, 9.0))


@pytest.mark.parametrize("degree", [0, 1, 3, 4])
def test_gradcheck_every_sh_degree(degree):
    _run_gradcheck(random_scene(6, 10 + degree, degree=degree), RasterSettings(20, 16, degree), (18.0, 18.0, 10.0, 8.0))


def test_gradcheck_partly_clipped_scene():
    """Gaussians straddling the image border, far outside the field of view (Jacobian clamp),
    behind the camera and close to the near plane."""
    gaussians = random_scene(12, 7, degree=1, spread=0.3)
    means = gaussians.means.clone()
    means[0] = torch.tensor([1.6, 0.0, 3.0])  # centre outside the image, tails inside
    means[1] = torch.tensor([0.0, -1.3, 3.0])
    means[2] = torch.tensor([6.0, 0.2, 2.0])  # far outside: culled
    means[3] = torch.tensor([0.1, 0.1, -2.0])  # behind the camera
    means[4] = torch.tensor([2.5, 0.1, 2.0])  # outside the fov margin, still drawn thanks to its size
    gaussians.means = means
    gaussians.scales[4] = torch.tensor([1.5, 0.4, 0.4], dtype=torch.float64)
    _run_gradcheck(gaussians, RasterSettings(24, 18, 1), (22.0, 22.0, 12.0, 9.0))


@pytest.mark.parametrize("dtype, tolerance", [(torch.float64, 1e-9), (torch.float32, 2e-3)])
@pytest.mark.parametrize("antialiased", [False, True])
def test_matches_the_autograd_twin(dtype, tolerance, antialiased):
    gaussians = random_scene(150, 3, degree=3, dtype=dtype)
    settings = RasterSettings(64, 48, 3, antialiased=antialiased)
    intrinsics = (55.0, 55.0, 32.0, 24.0)
    weights = [torch.randn(48, 64, 3, dtype=dtype), torch.randn(48, 64, dtype=dtype), torch.randn(48, 64, dtype=dtype)]
    results = []
    for rasterize in (RasterizeGaussians.apply, rasterize_reference):
        inputs = _inputs(gaussians)
        outputs = rasterize(*inputs, VIEW, intrinsics, settings)
        loss = sum((o * w).sum() for o, w in zip(outputs[:3], weights))
        results.append((outputs, torch.autograd.grad(loss, inputs)))
    (ours, our_grads), (twin, twin_grads) = results
    assert torch.equal(ours[3], twin[3])  # identical culling and radii
    for a, b in zip(ours[:3], twin[:3]):
        torch.testing.assert_close(a, b, atol=tolerance, rtol=tolerance)
    for name, a, b in zip(gaussians.tensors(), our_grads, twin_grads):
        scale = b.abs().max().clamp_min(1.0)
        assert (a - b).abs().max() <= tolerance * scale * 10, name


def test_background_gradient_and_expected_depth():
    from lumos3d_cli.render.render import render

    gaussians = random_scene(30, 5, degree=0)
    background = torch.tensor([0.2, 0.4, 0.6], dtype=torch.float64, requires_grad=True)
    output = render(gaussians, camera_at_origin(32, 24), background=background)
    output.images.sum().backward()
    expected = (1 - output.alphas.detach()).sum() * torch.ones(3, dtype=torch.float64)
    torch.testing.assert_close(background.grad, expected)
