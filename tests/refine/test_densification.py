"""Densification during refinement: the image-space gradient against autograd through a
projection, which Gaussians are split, cloned and pruned, the cap, the optimiser's moments, and a
refinement run that densifies (on buu's sparse points) at the extremes."""

import math

import pytest
import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.refine.densification import SPLIT_RADIUS_PX, SPLIT_SCALE_DIVISOR, GradientStatistics, densify
from lumos3d_cli.refine.parameters import GaussianParameters
from lumos3d_cli.refine.refinement import refine_gaussians
from lumos3d_cli.refine.settings import DensifySettings, RefineSettings
from lumos3d_cli.rotations import quaternion_to_matrix


def _camera() -> Cameras:
    angle = 0.3
    rotation = torch.tensor([[math.cos(angle), 0.0, math.sin(angle)], [0.0, 1.0, 0.0],
                             [-math.sin(angle), 0.0, math.cos(angle)]], dtype=torch.float64)
    extrinsics = torch.cat([rotation, torch.tensor([[0.2], [-0.1], [3.0]], dtype=torch.float64)], dim=1)
    intrinsics = torch.tensor([[400.0, 0, 320], [0, 380.0, 240], [0, 0, 1]], dtype=torch.float64)
    return Cameras(extrinsics[None], intrinsics[None], [(640, 480)])


def _gaussians(count: int, scale: float = 0.05) -> Gaussians:
    generator = torch.Generator().manual_seed(0)
    quats = torch.randn(count, 4, generator=generator, dtype=torch.float64)
    return Gaussians(torch.randn(count, 3, generator=generator, dtype=torch.float64) * 0.5,
                     quats / quats.norm(dim=-1, keepdim=True), torch.full((count, 3), scale, dtype=torch.float64),
                     torch.linspace(0.001, 0.9, count, dtype=torch.float64), torch.rand(count, 1, 3, generator=generator,
                                                                                         dtype=torch.float64))


def test_image_space_gradient_is_the_pixel_gradient_of_the_loss():
    """For a loss a u + b v of each mean's pixel (u, v), d loss / d pixel is (a, b): the
    statistics recover |(a, b)| from the world gradient autograd gives."""
    camera = _camera()
    means = (torch.randn(50, 3, dtype=torch.float64) * 0.5).requires_grad_(True)
    weights = torch.randn(50, 2, dtype=torch.float64)
    local = means @ camera.extrinsics[0, :, :3].T + camera.extrinsics[0, :, 3]
    u = camera.intrinsics[0, 0, 0] * local[:, 0] / local[:, 2] + camera.intrinsics[0, 0, 2]
    v = camera.intrinsics[0, 1, 1] * local[:, 1] / local[:, 2] + camera.intrinsics[0, 1, 2]
    (weights[:, 0] * u + weights[:, 1] * v).sum().backward()
    radii = torch.ones(50, 2, dtype=torch.int32)
    radii[:5] = 0  # not drawn in this view: no gradient counted
    statistics = GradientStatistics(50, torch.device("cpu"))
    statistics.add(means.grad, means.detach(), radii, camera)
    expected = weights.norm(dim=-1)
    torch.testing.assert_close(statistics.gradient_sum[5:], expected[5:], rtol=1e-10, atol=0)
    assert (statistics.gradient_sum[:5] == 0).all() and (statistics.views == (radii[:, 0] > 0)).all()
    statistics.add(means.grad, means.detach(), torch.ones(50, 2, dtype=torch.int32) * 7, camera)
    torch.testing.assert_close(statistics.mean_gradient()[:5], expected[:5], rtol=1e-10, atol=0)
    torch.testing.assert_close(statistics.mean_gradient()[5:], expected[5:], rtol=1e-10, atol=0)
    assert (statistics.largest_radius == 7).all()


def _densified(count: int, settings: DensifySettings, radius: float = 10.0):
    """A parameter set with an Adam state, gradients that rise with the index, every Gaussian
    drawn once at `radius` px; densified with `settings`."""
    gaussians = _gaussians(count)
    parameters = GaussianParameters(gaussians, "free", torch.zeros(1, 3, dtype=torch.float64), 1.0)
    leaves = [parameters.offsets, parameters.quats, parameters.log_scales, parameters.opacity_logits,
              parameters.colour, parameters.sh_rest]
    optimizer = torch.optim.Adam([{"params": [leaf]} for leaf in leaves if leaf.numel()], lr=1e-3)
    loss = sum((leaf * torch.arange(1, count + 1, dtype=torch.float64).reshape(-1, *[1] * (leaf.dim() - 1))).sum()
               for leaf in leaves)
    loss.backward()
    optimizer.step()
    before = {name: getattr(parameters, name).detach().clone() for name in ("quats", "log_scales", "opacity_logits", "colour")}
    means_before = parameters.means().detach().clone()
    moments_before = optimizer.state[parameters.colour]["exp_avg"].clone()
    statistics = GradientStatistics(count, torch.device("cpu"))
    statistics.gradient_sum += torch.arange(count, dtype=torch.float64)
    statistics.views += 1
    statistics.largest_radius += radius
    step = densify(parameters, optimizer, statistics, settings, torch.Generator().manual_seed(0))
    return parameters, optimizer, step, before, means_before, moments_before


def test_the_largest_gradients_are_split_and_the_transparent_pruned():
    count = 200
    parameters, optimizer, step, before, means_before, moments = _densified(count, DensifySettings(fraction=0.1))
    opacities = torch.sigmoid(before["opacity_logits"])
    alive = opacities >= 0.005
    chosen = torch.arange(count - int(0.1 * int(alive.sum())), count)  # the largest gradients are the last
    assert step.pruned == int((~alive).sum()) > 0
    assert step.split == len(chosen) and step.cloned == 0
    assert step.gaussians == int(alive.sum()) - len(chosen) + 2 * len(chosen) == len(parameters.quats)
    survivors = torch.nonzero(alive & ~torch.isin(torch.arange(count), chosen)).flatten()
    kept = len(survivors)
    torch.testing.assert_close(parameters.means()[:kept], means_before[survivors])
    torch.testing.assert_close(parameters.colour[:kept], before["colour"][survivors])
    # the halves: a third smaller by 3DGS's divisor, drawn around the parent within its scale
    halves = parameters.log_scales[kept:]
    parents = torch.cat([chosen, chosen])
    torch.testing.assert_close(halves, before["log_scales"][parents] - math.log(SPLIT_SCALE_DIVISOR))
    local = (quaternion_to_matrix(before["quats"][parents]).transpose(1, 2)
             @ (parameters.means()[kept:] - means_before[parents])[..., None])[..., 0]
    standardised = local / before["log_scales"][parents].exp()
    assert standardised.abs().max() < 6 and 0.5 < standardised.std() < 1.5
    # moments: kept for the survivors, zero for the new Gaussians; the optimiser steps the new leaves
    state = optimizer.state[parameters.colour]
    torch.testing.assert_close(state["exp_avg"][:kept], moments[survivors])
    assert (state["exp_avg"][kept:] == 0).all() and (state["exp_avg_sq"][kept:] == 0).all()
    assert any(parameters.colour is p for group in optimizer.param_groups for p in group["params"])
    leaves = {id(p) for group in optimizer.param_groups for p in group["params"]}
    assert set(map(id, optimizer.state)) <= leaves and len(optimizer.state) == len(leaves)  # the old leaves are gone
    assert int(state["step"]) == 1
    parameters.gaussians().sh.sum().backward()
    optimizer.step()
    assert torch.isfinite(parameters.colour).all()


def test_small_gaussians_are_cloned_and_the_cap_holds():
    count = 200
    cap = 207  # 199 stay after pruning the most transparent: room for 8
    parameters, _, step, before, means_before, _ = _densified(
        count, DensifySettings(fraction=0.5, max_gaussians=cap), radius=SPLIT_RADIUS_PX)
    assert step.pruned == 1 and step.split == 0 and step.cloned == 8 and step.gaussians == cap == len(parameters.quats)
    torch.testing.assert_close(parameters.means()[-8:], means_before[-8:])  # a clone sits on its parent
    full = _densified(count, DensifySettings(fraction=0.5, max_gaussians=10), radius=1.0)[2]
    assert full.cloned == 0 and full.split == 0  # more survivors than the cap: nothing added (the budget caps the scene)


def test_a_scene_turned_transparent_is_not_emptied():
    gaussians = _gaussians(20)
    gaussians = Gaussians(gaussians.means, gaussians.quats, gaussians.scales, torch.full((20,), 1e-4, dtype=torch.float64),
                          gaussians.sh)
    parameters = GaussianParameters(gaussians, "free", torch.zeros(1, 3, dtype=torch.float64), 1.0)
    optimizer = torch.optim.Adam([parameters.offsets, parameters.colour], lr=1e-3)
    statistics = GradientStatistics(20, torch.device("cpu"))
    step = densify(parameters, optimizer, statistics, DensifySettings(), torch.Generator().manual_seed(0))
    assert step.pruned == 0 and step.gaussians == 20


def test_settings_refuse_what_cannot_densify():
    with pytest.raises(ValueError, match="fraction"):
        DensifySettings(fraction=1.5)
    with pytest.raises(ValueError, match="every"):
        DensifySettings(every=0)
    with pytest.raises(ValueError, match="free positions"):
        RefineSettings(positions="ray", densify=DensifySettings())
    with pytest.raises(ValueError, match="one view per step"):
        RefineSettings(views_per_step=2, densify=DensifySettings())
    assert DensifySettings(every=5, until=10).due(10, 15) and not DensifySettings(every=5, until=9).due(10, 15)
    assert not DensifySettings(every=5, until=100).due(10, 14)  # the last 5 steps fit what the last densification made


@pytest.mark.parametrize("scale", [1e-6, 1.0])
def test_refinement_densifies_within_the_cap(sparse_buu, scale):
    """On buu's sparse points (and the same points degenerate, a millionth of their size) the
    scene grows by the densified share, never past the cap, stays finite and fits better."""
    gaussians = sparse_buu.gaussians
    if scale != 1.0:
        gaussians = Gaussians(gaussians.means, gaussians.quats, gaussians.scales * scale, gaussians.opacities, gaussians.sh)
    cap = len(gaussians) + 150
    settings = RefineSettings(steps=12, max_side=64, patience=1000,
                              densify=DensifySettings(every=4, until=8, fraction=0.1, max_gaussians=cap))
    plain = refine_gaussians(gaussians, sparse_buu.cameras, sparse_buu.targets, RefineSettings(steps=12, max_side=64, patience=1000))
    result = refine_gaussians(gaussians, sparse_buu.cameras, sparse_buu.targets, settings)
    result.gaussians.require_finite()
    assert len(gaussians) < len(result.gaussians) <= cap
    assert math.isfinite(result.loss_curve[-1]) and result.loss_curve[-1] < result.loss_curve[0]
    if scale == 1.0:
        assert sum(result.loss_curve[-3:]) < sum(plain.loss_curve[-3:]) * 1.02
    again = refine_gaussians(gaussians, sparse_buu.cameras, sparse_buu.targets, settings)
    torch.testing.assert_close(again.gaussians.means, result.gaussians.means)  # seeded: repeatable


def test_one_view_densifies(sparse_buu):
    settings = RefineSettings(steps=6, max_side=64, patience=1000, densify=DensifySettings(every=3, fraction=0.2))
    result = refine_gaussians(sparse_buu.gaussians, sparse_buu.cameras[[0]], sparse_buu.targets[:1], settings)
    result.gaussians.require_finite()
    assert len(result.gaussians) > len(sparse_buu.gaussians)
