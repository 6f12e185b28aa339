"""Refinement's Adam (refine/adam.py) against torch.optim.Adam, the oracle: the same updates,
the same state, several groups with their own and changing rates, gradients missing on some
steps, degenerate values; and refinement never imports torch._dynamo."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from lumos3d_cli.refine.adam import FusedAdam


def _pair(shapes, rates, eps):
    generator = torch.Generator().manual_seed(0)
    ours = [torch.randn(shape, generator=generator, dtype=torch.float32).requires_grad_() for shape in shapes]
    theirs = [tensor.detach().clone().requires_grad_() for tensor in ours]
    fused = FusedAdam(list(zip(ours, rates)), eps=eps)
    reference = torch.optim.Adam([{"params": [tensor], "lr": lr} for tensor, lr in zip(theirs, rates)], eps=eps)
    return ours, theirs, fused, reference


@pytest.mark.parametrize("eps", [1e-8, 1e-15])
def test_matches_torch_adam_over_steps_with_changing_rates(eps):
    shapes, rates = [(50, 3), (50, 4), (50,), (7, 15, 3)], [1e-2, 1e-3, 5e-2, 2.5e-3]
    ours, theirs, fused, reference = _pair(shapes, rates, eps)
    generator = torch.Generator().manual_seed(1)
    for step in range(12):
        gradients = [torch.randn(tensor.shape, generator=generator) * 10.0 ** (step % 4 - 6) for tensor in ours]
        skipped = step % 5 == 3  # the second group gets no gradient on some steps: it must not move
        for tensor, other, gradient in zip(ours, theirs, gradients):
            tensor.grad, other.grad = gradient.clone(), gradient.clone()
        if skipped:
            ours[1].grad = theirs[1].grad = None
        before = ours[1].detach().clone()
        fused.step()
        reference.step()
        if skipped:
            assert torch.equal(ours[1], before)
        for tensor, other in zip(ours, theirs):
            torch.testing.assert_close(tensor, other, rtol=1e-5, atol=1e-7)
        for group, other_group in zip(fused.param_groups, reference.param_groups):
            group["lr"] = other_group["lr"] = group["lr"] * 0.9
    for tensor, other in zip(ours, theirs):
        mine, oracle = fused.state[tensor], reference.state[other]
        assert float(mine["step"]) == float(oracle["step"])
        torch.testing.assert_close(mine["exp_avg"], oracle["exp_avg"], rtol=1e-5, atol=1e-12)
        torch.testing.assert_close(mine["exp_avg_sq"], oracle["exp_avg_sq"], rtol=1e-5, atol=1e-20)


def test_zero_and_tiny_gradients_stay_finite():
    """eps 1e-15 (3DGS's): a zero gradient leaves the tensor where it is, a gradient of 1e-12
    still moves it by about the learning rate, never by inf or NaN."""
    tensor = torch.ones(4, requires_grad=True)
    fused = FusedAdam([(tensor, 1e-2)], eps=1e-15)
    tensor.grad = torch.tensor([0.0, 1e-12, -1e-12, 1e3])
    fused.step()
    assert torch.isfinite(tensor).all()
    torch.testing.assert_close(tensor.detach(), torch.tensor([1.0, 1 - 1e-2, 1 + 1e-2, 1 - 1e-2]))
    fused.zero_grad()
    assert tensor.grad is None


def test_refuses_devices_without_the_fused_kernel():
    tensor = torch.zeros(3, device="meta", requires_grad=True)
    with pytest.raises(ValueError, match="meta"):
        FusedAdam([(tensor, 1e-3)])


def test_refinement_does_not_import_dynamo():
    """torch.optim's step imports torch._dynamo (seconds of a restore's CPU); refinement's must not."""
    script = """
import sys, torch
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.refine.refinement import refine_gaussians
from lumos3d_cli.refine.settings import RefineSettings
g = torch.Generator().manual_seed(0)
n = 200
means = torch.rand(n, 3, generator=g) - 0.5
means[:, 2] += 3.0
quats = torch.zeros(n, 4); quats[:, 0] = 1
gaussians = Gaussians(means, quats, torch.full((n, 3), 0.05), torch.full((n,), 0.8), torch.rand(n, 1, 3, generator=g))
extrinsics = torch.eye(4)[:3][None].repeat(2, 1, 1)
extrinsics[1, 0, 3] = 0.1
intrinsics = torch.tensor([[40.0, 0, 32], [0, 40.0, 24], [0, 0, 1]])[None].repeat(2, 1, 1)
cameras = Cameras(extrinsics, intrinsics, [(64, 48)] * 2)
refine_gaussians(gaussians, cameras, torch.rand(2, 3, 48, 64, generator=g), RefineSettings(steps=3, max_side=64))
print("torch._dynamo" in sys.modules)
"""
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"
