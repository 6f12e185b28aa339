"""The projection kernel stage by stage against the pure-torch twin (render/reference.py), in
float64, in the manner of gsplat's tests/test_basic.py: the covariance, the EWA projection, the
conic and the SH colour each forward against the twin's stage and each hand-written gradient piece
against autograd through that stage; then the whole kernel output by output (means2d, conics,
depths, opacities, colours, radii), each output's backward on its own."""

import numpy as np
import pytest
import torch
from numba import njit

from lumos3d_cli.render.kernels.projection import (
    camera_centre,
    camera_mean_backward,
    clamped_xy,
    conic,
    conic_backward,
    cov2d,
    cov2d_backward,
    covariance_backward,
    covariances,
    ewa_jacobian,
    project_backward,
    projected_covariance,
    quaternion_backward,
    rotation,
    sh_colour,
    sh_colour_backward,
    unit_quaternion,
    view_direction,
)
from lumos3d_cli.render.kernels.sh import sh_basis
from lumos3d_cli.render.rasterizer import project
from lumos3d_cli.render.reference import (
    colours_reference,
    conic_reference,
    covariance_reference,
    ewa_reference,
    project_reference,
    world_to_camera_reference,
)
from lumos3d_cli.render.settings import RasterSettings
from lumos3d_cli.rotations import quaternion_to_matrix

from factories import random_scene

WIDTH, HEIGHT = 40, 30
INTRINSICS = (36.0, 34.0, 19.0, 16.0)
EPS2D = 0.3


def _viewmat(seed: int) -> torch.Tensor:
    """A [3,4] world->camera matrix with a random rotation, so that R_view is exercised."""
    g = torch.Generator().manual_seed(seed)
    rotation_matrix = quaternion_to_matrix(torch.randn(4, generator=g, dtype=torch.float64))
    return torch.cat([rotation_matrix, torch.randn(3, 1, generator=g, dtype=torch.float64)], dim=1)


def _to_world(camera_points: torch.Tensor, viewmat: torch.Tensor) -> torch.Tensor:
    """World points [N,3] whose camera-space positions under viewmat are camera_points [N,3]."""
    return (camera_points - viewmat[:, 3]) @ viewmat[:, :3]


def _leaves(*tensors):
    return [t.detach().clone().requires_grad_(True) for t in tensors]


def _close(ours: np.ndarray, expected: torch.Tensor, tolerance: float = 1e-10, name: str = ""):
    """Agreement to `tolerance` relative to the largest expected magnitude (at least 1)."""
    expected = expected.detach()
    scale = max(expected.abs().max().item(), 1.0) if expected.numel() else 1.0
    torch.testing.assert_close(torch.from_numpy(np.asarray(ours, dtype=np.float64)), expected, rtol=0, atol=tolerance * scale, msg=name)


# Covariance: quaternion and scales -> world covariance -> camera covariance.


@njit
def _camera_covariances(quats, scales, viewmat):
    n = quats.shape[0]
    out = np.empty((n, 3, 3))
    q, rq, cov, scratch = np.empty(4), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    for i in range(n):
        unit_quaternion(quats, i, q)
        rotation(q, rq)
        covariances(rq, scales, i, viewmat, cov, out[i], scratch)
    return out


@njit
def _covariance_gradients(quats, scales, viewmat, v_cov_c):
    n = quats.shape[0]
    v_quats, v_scales = np.zeros((n, 4)), np.zeros((n, 3))
    q, rq, v_cov, v_rq, scratch = np.empty(4), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    for i in range(n):
        qnorm = unit_quaternion(quats, i, q)
        rotation(q, rq)
        covariance_backward(viewmat, rq, scales, i, v_cov_c[i], v_cov, v_rq, scratch, v_scales)
        quaternion_backward(q, qnorm, v_rq, v_quats, i)
    return v_quats, v_scales


def test_covariance_stage():
    g = torch.Generator().manual_seed(1)
    quats = torch.randn(64, 4, generator=g, dtype=torch.float64) * 2
    quats[0] = 0.0  # degenerate: the identity, and no gradient
    scales = torch.rand(64, 3, generator=g, dtype=torch.float64) + 0.05
    viewmat = _viewmat(2)
    quats_leaf, scales_leaf = _leaves(quats, scales)
    _, twin = world_to_camera_reference(torch.zeros(64, 3, dtype=torch.float64), covariance_reference(quats_leaf, scales_leaf), viewmat)
    _close(_camera_covariances(quats.numpy(), scales.numpy(), viewmat.numpy()), twin, name="camera covariance")

    v_cov_c = torch.randn(64, 3, 3, generator=g, dtype=torch.float64)  # not symmetric: both halves count
    expected = torch.autograd.grad((twin * v_cov_c).sum(), [quats_leaf, scales_leaf])
    ours = _covariance_gradients(quats.numpy(), scales.numpy(), viewmat.numpy(), v_cov_c.numpy())
    for name, a, b in zip(("v_quats", "v_scales"), ours, expected):
        _close(a, b, name=name)
    assert not ours[0][0].any()


# EWA projection: camera-space mean and covariance -> means2d, depth, 2D covariance.


@njit
def _projected_covariances(means_c, cov_c, fx, fy, cx, cy, width, height):
    n = means_c.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        x, y, z = means_c[i, 0], means_c[i, 1], means_c[i, 2]
        tx, ty, _, _ = clamped_xy(x, y, z, fx, fy, cx, cy, width, height)
        out[i, 0], out[i, 1], out[i, 2] = cov2d(cov_c[i], ewa_jacobian(z, tx, ty, fx, fy))
    return out


@njit
def _ewa_gradients(means_c, cov_c, fx, fy, cx, cy, width, height, v_means2d, v_depths, v_cov2d):
    n = means_c.shape[0]
    v_means_c, v_cov_c, jm = np.zeros((n, 3)), np.zeros((n, 3, 3)), np.empty((3, 3))
    for i in range(n):
        x, y, z = means_c[i, 0], means_c[i, 1], means_c[i, 2]
        clamp = clamped_xy(x, y, z, fx, fy, cx, cy, width, height)
        jacobian = ewa_jacobian(z, clamp[0], clamp[1], fx, fy)
        v_cov = (v_cov2d[i, 0], v_cov2d[i, 1], v_cov2d[i, 2])
        v_jacobian = cov2d_backward(cov_c[i], jacobian, v_cov, v_cov_c[i], jm)
        v_mean2d = (v_means2d[i, 0], v_means2d[i, 1])
        v_means_c[i, 0], v_means_c[i, 1], v_means_c[i, 2] = camera_mean_backward(
            x, y, z, fx, fy, clamp, v_mean2d, v_depths[i], v_jacobian
        )
    return v_means_c, v_cov_c


def test_ewa_stage_including_the_clamped_jacobian():
    g = torch.Generator().manual_seed(3)
    z = 1.0 + 4 * torch.rand(80, generator=g, dtype=torch.float64)
    # Half inside the view, half beyond the field-of-view margin on either axis (J clamped).
    spread = torch.where(torch.arange(80) < 40, 0.4, 3.0).to(torch.float64)
    xy = (torch.rand(80, 2, generator=g, dtype=torch.float64) * 2 - 1) * spread[:, None] * z[:, None]
    means_c = torch.cat([xy, z[:, None]], dim=1)
    m = torch.randn(80, 3, 3, generator=g, dtype=torch.float64) * 0.2
    cov_c = m @ m.transpose(1, 2)
    means_leaf, cov_leaf = _leaves(means_c, cov_c)
    means2d, twin_cov2d = ewa_reference(means_leaf, cov_leaf, INTRINSICS, float(WIDTH), float(HEIGHT))
    ours = _projected_covariances(means_c.numpy(), cov_c.numpy(), *INTRINSICS, float(WIDTH), float(HEIGHT))
    _close(ours, torch.stack([twin_cov2d[:, 0, 0], twin_cov2d[:, 0, 1], twin_cov2d[:, 1, 1]], dim=1), name="cov2d")

    v_means2d = torch.randn(80, 2, generator=g, dtype=torch.float64)
    v_depths = torch.randn(80, generator=g, dtype=torch.float64)
    v_cov2d = torch.randn(80, 3, generator=g, dtype=torch.float64)  # w.r.t. (a, b, c), b counted once
    loss = (
        (means2d * v_means2d).sum() + (means_leaf[:, 2] * v_depths).sum()
        + (twin_cov2d[:, 0, 0] * v_cov2d[:, 0] + twin_cov2d[:, 0, 1] * v_cov2d[:, 1] + twin_cov2d[:, 1, 1] * v_cov2d[:, 2]).sum()
    )
    v_means_c, v_cov_c = torch.autograd.grad(loss, [means_leaf, cov_leaf])
    # Only the symmetric part of a covariance's gradient is defined; the kernel returns it.
    expected = (v_means_c, 0.5 * (v_cov_c + v_cov_c.transpose(1, 2)))
    ours = _ewa_gradients(
        means_c.numpy(), cov_c.numpy(), *INTRINSICS, float(WIDTH), float(HEIGHT),
        v_means2d.numpy(), v_depths.numpy(), v_cov2d.numpy(),
    )
    for name, a, b in zip(("v_means_c", "v_cov_c"), ours, expected):
        _close(a, b, name=name)


# Conic: 2D covariance and opacity -> dilated inverse and compensated opacity.


@njit
def _conics(cov2d_entries, opacities, eps2d, antialiased):
    n = cov2d_entries.shape[0]
    conics, opacities_eff = np.empty((n, 3)), np.empty(n)
    for i in range(n):
        a, b, c, _, compensation = conic(cov2d_entries[i, 0], cov2d_entries[i, 1], cov2d_entries[i, 2], eps2d, antialiased)
        conics[i, 0], conics[i, 1], conics[i, 2] = a, b, c
        opacities_eff[i] = opacities[i] * compensation
    return conics, opacities_eff


@njit
def _forward_projected_covariances(quats, scales, viewmat, jacobians):
    n = quats.shape[0]
    out = np.empty((n, 3))
    q, rq = np.empty(4), np.empty((3, 3))
    for i in range(n):
        unit_quaternion(quats, i, q)
        rotation(q, rq)
        jacobian = (jacobians[i, 0], jacobians[i, 1], jacobians[i, 2], jacobians[i, 3])
        out[i, 0], out[i, 1], out[i, 2] = projected_covariance(rq, scales, i, viewmat, jacobian)
    return out


@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e4])
def test_the_forward_passes_2d_covariance_is_the_twins(scale):
    """The forward pass's shortcut (projected_covariance: J R_view R_q S as one 2x3 product) against
    the twin's world covariance -> camera covariance -> EWA chain, at tiny, unit and huge scales."""
    g = torch.Generator().manual_seed(7)
    quats = torch.randn(64, 4, generator=g, dtype=torch.float64)
    quats[0] = 0.0  # degenerate: the identity
    scales = (torch.rand(64, 3, generator=g, dtype=torch.float64) + 0.05) * scale
    scales[1] = torch.tensor([1e-3, 1.0, 1e3], dtype=torch.float64) * scale  # needle-like
    viewmat = _viewmat(8)
    jacobians = torch.randn(64, 4, generator=g, dtype=torch.float64) * 30
    _, cov_c = world_to_camera_reference(torch.zeros(64, 3, dtype=torch.float64), covariance_reference(quats, scales), viewmat)
    j = torch.zeros(64, 2, 3, dtype=torch.float64)
    j[:, 0, 0], j[:, 0, 2], j[:, 1, 1], j[:, 1, 2] = jacobians.unbind(1)
    twin = j @ cov_c @ j.transpose(1, 2)
    ours = _forward_projected_covariances(quats.numpy(), scales.numpy(), viewmat.numpy(), jacobians.numpy())
    _close(ours, torch.stack([twin[:, 0, 0], twin[:, 0, 1], twin[:, 1, 1]], dim=1), tolerance=1e-12, name="cov2d")


@njit
def _conic_gradients(cov2d_entries, opacities, eps2d, antialiased, v_conics, v_opacities_eff):
    n = cov2d_entries.shape[0]
    v_cov2d, v_opacities = np.empty((n, 3)), np.empty(n)
    for i in range(n):
        v_conic = (v_conics[i, 0], v_conics[i, 1], v_conics[i, 2])
        v_cov2d[i, 0], v_cov2d[i, 1], v_cov2d[i, 2], v_opacities[i] = conic_backward(
            cov2d_entries[i, 0], cov2d_entries[i, 1], cov2d_entries[i, 2], eps2d, antialiased, opacities[i],
            v_conic, v_opacities_eff[i],
        )
    return v_cov2d, v_opacities


@pytest.mark.parametrize("antialiased", [False, True])
def test_conic_stage_including_the_compensation_floor(antialiased):
    g = torch.Generator().manual_seed(4)
    m = torch.randn(60, 2, 2, generator=g, dtype=torch.float64)
    cov = m @ m.transpose(1, 2) + 0.01 * torch.eye(2, dtype=torch.float64)
    cov[0] = torch.tensor([[1.0, 1.0 - 1e-9], [1.0 - 1e-9, 1.0]])  # nearly singular: compensation floored
    opacities = torch.rand(60, generator=g, dtype=torch.float64)
    cov_leaf, opacities_leaf = _leaves(cov, opacities)
    twin_conics, twin_opacities = conic_reference(cov_leaf, opacities_leaf, EPS2D, antialiased)
    entries = torch.stack([cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]], dim=1).numpy()
    ours = _conics(entries, opacities.numpy(), EPS2D, antialiased)
    _close(ours[0], twin_conics, name="conics")
    _close(ours[1], twin_opacities, name="opacities")

    v_conics = torch.randn(60, 3, generator=g, dtype=torch.float64)
    v_opacities = torch.randn(60, generator=g, dtype=torch.float64)
    v_cov, v_opacity = torch.autograd.grad(
        (twin_conics * v_conics).sum() + (twin_opacities * v_opacities).sum(), [cov_leaf, opacities_leaf]
    )
    ours = _conic_gradients(entries, opacities.numpy(), EPS2D, antialiased, v_conics.numpy(), v_opacities.numpy())
    # The twin reads b from cov2d[0, 1] only, so its gradient lands there.
    _close(ours[0], torch.stack([v_cov[:, 0, 0], v_cov[:, 0, 1], v_cov[:, 1, 1]], dim=1), name="v_cov2d")
    _close(ours[1], v_opacity, name="v_opacities")


# SH colour: coefficients and the view direction -> colours clamped at 0.


@njit
def _colours(means, sh, campos, degree):
    n = means.shape[0]
    colours, basis = np.empty((n, 3)), np.empty((degree + 1) ** 2)
    for i in range(n):
        ux, uy, uz, _ = view_direction(means, i, campos)
        sh_basis(degree, ux, uy, uz, basis)
        for ch in range(3):
            colours[i, ch] = max(sh_colour(sh, i, degree, basis, ch), 0.0)
    return colours


@njit
def _colour_gradients(means, sh, campos, degree, v_colours):
    n = means.shape[0]
    v_means, v_sh = np.zeros((n, 3)), np.zeros(sh.shape)
    basis, weights = np.empty((degree + 1) ** 2), np.empty((degree + 1) ** 2)
    for i in range(n):
        v_means[i, 0], v_means[i, 1], v_means[i, 2] = sh_colour_backward(
            sh, i, degree, view_direction(means, i, campos), v_colours, v_sh, basis, weights
        )
    return v_means, v_sh


@pytest.mark.parametrize("degree", [0, 1, 2, 3, 4])
def test_sh_colour_stage_including_the_clamp_at_zero(degree):
    g = torch.Generator().manual_seed(5 + degree)
    means = torch.randn(50, 3, generator=g, dtype=torch.float64) * 2
    sh = torch.randn(50, (degree + 1) ** 2, 3, generator=g, dtype=torch.float64)
    sh[:10, 0] = -10.0  # clamped at 0: no gradient through those channels
    sh[:10, 1:] *= 0.1
    campos = torch.tensor([0.3, -0.2, -4.0], dtype=torch.float64)
    means_leaf, sh_leaf = _leaves(means, sh)
    twin = colours_reference(means_leaf, sh_leaf, campos, degree)
    assert (twin[:10] == 0).all()
    _close(_colours(means.numpy(), sh.numpy(), campos.numpy(), degree), twin, name="colours")

    v_colours = torch.randn(50, 3, generator=g, dtype=torch.float64)
    expected = torch.autograd.grad((twin * v_colours).sum(), [means_leaf, sh_leaf], allow_unused=True)
    expected = [torch.zeros_like(means) if expected[0] is None else expected[0], expected[1]]  # degree 0: no direction
    ours = _colour_gradients(means.numpy(), sh.numpy(), campos.numpy(), degree, v_colours.numpy())
    for name, a, b in zip(("v_means", "v_sh"), ours, expected):
        _close(a, b, name=name)


# The whole kernel, output by output.

OUTPUTS = ("means2d", "conics", "depths", "opacities", "colours")


def _scene(seed: int):
    """Gaussians seen by a rotated camera: most in view, some straddling the border or beyond the
    field-of-view margin (clamped Jacobian), one behind the camera, with SH degree 3."""
    gaussians = random_scene(60, seed, degree=3, spread=0.6, depth=3.0)
    camera_points = gaussians.means.clone()
    camera_points[0] = torch.tensor([2.2, 0.1, 2.0], dtype=torch.float64)  # beyond the margin, drawn
    camera_points[1] = torch.tensor([1.9, -1.2, 3.0], dtype=torch.float64)  # straddling a corner
    camera_points[2] = torch.tensor([0.1, 0.2, -1.0], dtype=torch.float64)  # behind: culled
    gaussians.scales[0] = torch.tensor([1.2, 0.5, 0.5], dtype=torch.float64)
    viewmat = _viewmat(seed)
    gaussians.means = _to_world(camera_points, viewmat)
    return gaussians, viewmat


@pytest.mark.parametrize("antialiased", [False, True])
def test_projection_kernel_output_by_output(antialiased):
    settings = RasterSettings(WIDTH, HEIGHT, 3, eps2d=EPS2D, antialiased=antialiased)
    gaussians, viewmat = _scene(8)
    ours = project(*gaussians.tensors().values(), viewmat, INTRINSICS, settings)
    arrays = [t.numpy() for t in gaussians.tensors().values()]
    leaves = _leaves(*gaussians.tensors().values())
    *twin, twin_radii = project_reference(*leaves, viewmat, INTRINSICS, settings)

    torch.testing.assert_close(torch.from_numpy(ours[5]), twin_radii, rtol=0, atol=0)
    drawn = (twin_radii > 0).any(dim=1)
    assert drawn[:2].all() and not drawn[2] and drawn.sum() > 40
    for name, a, b in zip(OUTPUTS, ours[:5], twin):
        _close(a[drawn.numpy()], b[drawn], name=name)

    g = torch.Generator().manual_seed(9)
    for index, name in enumerate(OUTPUTS):
        cotangents = [np.zeros_like(o) for o in ours[:5]]
        v_output = torch.randn(twin[index].shape, generator=g, dtype=torch.float64)
        v_output[~drawn] = 0.0  # the kernel leaves culled Gaussians alone
        cotangents[index] = v_output.numpy()
        expected = torch.autograd.grad((twin[index] * v_output).sum(), leaves, retain_graph=True, allow_unused=True)
        gradients = [np.zeros_like(a) for a in arrays]
        project_backward(
            *arrays, viewmat.numpy(), *INTRINSICS, float(WIDTH), float(HEIGHT), 3, EPS2D, antialiased, ours[5],
            *cotangents, *gradients,
        )
        for parameter, a, b in zip(gaussians.tensors(), gradients, expected):
            b = torch.zeros(a.shape, dtype=torch.float64) if b is None else b
            _close(a, b, name=f"d {name} / d {parameter}")


def test_camera_centre_is_where_the_view_direction_starts():
    """The SH direction of a Gaussian on the optical axis is the camera's forward axis."""
    viewmat = _viewmat(11)
    centre = camera_centre(viewmat.numpy())
    on_axis = _to_world(torch.tensor([[0.0, 0.0, 5.0]], dtype=torch.float64), viewmat).numpy()
    ux, uy, uz, length = view_direction(on_axis, 0, centre)
    np.testing.assert_allclose([ux, uy, uz], viewmat[2, :3].numpy(), atol=1e-12)
    assert length == pytest.approx(5.0)
