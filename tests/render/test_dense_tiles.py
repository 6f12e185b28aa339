"""Dense tiles against the pure-torch twin: hundreds of Gaussians per 16x16 tile (the kernel reads
a tile's entries in blocks of 64 and recounts finished pixels once a block), pixels that reach
the transmittance threshold, and an image whose size is not a multiple of the tile."""

import pytest
import torch

from lumos3d_cli.render.rasterizer import RasterizeGaussians, composite, rasterize_with_weights
from lumos3d_cli.render.reference import rasterize_reference, rasterize_with_weights_reference
from lumos3d_cli.render.settings import RasterSettings

from factories import random_scene

VIEW = torch.eye(4, dtype=torch.float64)[:3]
SETTINGS = RasterSettings(37, 21, 1)  # 3 x 2 tiles, the last column and row partly outside
INTRINSICS = (30.0, 30.0, 18.5, 10.5)


def _dense_scene(dtype):
    gaussians = random_scene(400, 11, degree=1, dtype=dtype, spread=0.3)
    gaussians.opacities[:100] = 0.97  # enough near-opaque layers for pixels to finish
    return gaussians


def test_the_scene_is_dense_and_saturates():
    gaussians = _dense_scene(torch.float64)
    _, (tile_offsets, _, _), _, _, transmittance, _, _ = composite(
        *gaussians.tensors().values(), VIEW, INTRINSICS, SETTINGS, entry_weights=False
    )
    assert (tile_offsets[1:] - tile_offsets[:-1]).max() > 3 * 64
    assert transmittance.min() < 1e-3


@pytest.mark.parametrize("dtype, tolerance", [(torch.float64, 1e-9), (torch.float32, 2e-3)])
def test_dense_tiles_match_the_twin(dtype, tolerance):
    gaussians = _dense_scene(dtype)
    g = torch.Generator().manual_seed(0)
    weights = [torch.randn(21, 37, 3, generator=g, dtype=dtype), torch.randn(21, 37, generator=g, dtype=dtype),
               torch.randn(21, 37, generator=g, dtype=dtype)]
    results = []
    for rasterize in (RasterizeGaussians.apply, rasterize_reference):
        inputs = [t.clone().requires_grad_(True) for t in gaussians.tensors().values()]
        outputs = rasterize(*inputs, VIEW, INTRINSICS, SETTINGS)
        loss = sum((o * w).sum() for o, w in zip(outputs[:3], weights))
        results.append((outputs, torch.autograd.grad(loss, inputs)))
    (ours, our_grads), (twin, twin_grads) = results
    assert torch.equal(ours[3], twin[3])
    for a, b in zip(ours[:3], twin[:3]):
        torch.testing.assert_close(a, b, atol=tolerance, rtol=tolerance)
    for name, a, b in zip(gaussians.tensors(), our_grads, twin_grads):
        scale = b.abs().max().clamp_min(1.0)
        assert (a - b).abs().max() <= tolerance * scale * 10, name


@pytest.mark.parametrize("dtype, tolerance", [(torch.float64, 1e-9), (torch.float32, 1e-4)])
def test_dense_tile_weights_match_the_twin(dtype, tolerance):
    gaussians = _dense_scene(dtype)
    ours = rasterize_with_weights(*gaussians.tensors().values(), VIEW, INTRINSICS, SETTINGS)
    twin = rasterize_with_weights_reference(*gaussians.tensors().values(), VIEW, INTRINSICS, SETTINGS)
    for a, b in zip(ours, twin):
        torch.testing.assert_close(a, b, atol=tolerance, rtol=tolerance)
