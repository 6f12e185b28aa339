"""Camera corrections through the CPU rasterizer: moving the Gaussians by W = V^-1 D V renders
what the corrected camera D V sees, and the gradients of the corrections match finite
differences (gradcheck, float64) and the pure-torch twin differentiated through its camera."""

import pytest
import torch

from lumos3d_cli.io.cameras import Cameras, make_intrinsics
from lumos3d_cli.refine.camera_corrections import (
    CameraCorrections,
    axis_angle_to_matrix,
    axis_angle_to_quaternion,
)
from lumos3d_cli.render.reference import rasterize_reference
from lumos3d_cli.render.render import render
from lumos3d_cli.render.settings import RasterSettings
from lumos3d_cli.rotations import quaternion_to_matrix

from factories import random_scene

WIDTH, HEIGHT = 24, 18
INTRINSICS = (22.0, 22.0, 12.0, 9.0)


def _camera(seed: int = 0) -> Cameras:
    """A camera a little off the identity, looking at random_scene's cloud around z = 3."""
    generator = torch.Generator().manual_seed(seed)
    rotation = axis_angle_to_matrix(0.05 * torch.randn(3, generator=generator, dtype=torch.float64))
    translation = 0.1 * torch.randn(3, 1, generator=generator, dtype=torch.float64)
    return Cameras(torch.cat([rotation, translation], 1)[None], make_intrinsics(*INTRINSICS), [(WIDTH, HEIGHT)])


def _corrections(camera: Cameras, omega, tau) -> CameraCorrections:
    corrections = CameraCorrections(camera.extrinsics, torch.tensor([False]))
    with torch.no_grad():
        corrections.rotations[0] = torch.tensor(omega, dtype=torch.float64)
        corrections.translations[0] = torch.tensor(tau, dtype=torch.float64)
    return corrections


@pytest.mark.parametrize("omega", [[0.0, 0.0, 0.0], [1e-6, -2e-6, 0.0], [0.3, -0.2, 0.5], [3.0, 0.0, 0.1]])
def test_axis_angle_matrix_and_quaternion_agree(omega):
    omega = torch.tensor(omega, dtype=torch.float64)
    matrix = axis_angle_to_matrix(omega)
    torch.testing.assert_close(matrix @ matrix.T, torch.eye(3, dtype=torch.float64), atol=1e-12, rtol=0)
    torch.testing.assert_close(quaternion_to_matrix(axis_angle_to_quaternion(omega)), matrix, atol=1e-12, rtol=0)
    torch.testing.assert_close(matrix @ omega, omega)  # the axis is fixed


def test_axis_angle_is_smooth_through_zero():
    omega = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(axis_angle_to_matrix, (omega,))
    assert torch.autograd.gradcheck(axis_angle_to_quaternion, (omega,))


@pytest.mark.parametrize("degree", [0, 2])
def test_moved_gaussians_render_what_the_corrected_camera_sees(degree):
    gaussians = random_scene(40, 3, degree=degree)
    camera = _camera()
    corrections = _corrections(camera, [0.02, -0.03, 0.01], [0.05, -0.02, 0.03])
    corrected = Cameras(corrections.corrected_extrinsics(), camera.intrinsics, camera.sizes)
    expected = render(gaussians, corrected).images
    moved = render(corrections.moved_gaussians(0, gaussians, degree), camera).images
    torch.testing.assert_close(moved, expected, atol=1e-9, rtol=1e-9)


def _projected_render(corrections: CameraCorrections, gaussians, camera, degree, weights):
    """(omega, tau) -> the render of the corrected camera projected on `weights` [P, 1, 3, H, W]
    (P numbers: gradcheck runs one backward per output)."""
    def function(omega, tau):
        corrections.rotations, corrections.translations = omega[None], tau[None]
        images = render(corrections.moved_gaussians(0, gaussians, degree), camera).images
        return (images[None] * weights).flatten(1).sum(1)
    return function


@pytest.mark.parametrize("degree", [0, 1])
def test_gradcheck_of_the_corrections_through_the_cpu_rasterizer(degree):
    gaussians = random_scene(10, 5, degree=degree, spread=0.4)
    camera = _camera(1)
    corrections = _corrections(camera, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    omega = torch.tensor([0.01, -0.02, 0.015], dtype=torch.float64, requires_grad=True)
    tau = torch.tensor([0.03, 0.01, -0.02], dtype=torch.float64, requires_grad=True)
    weights = torch.randn(4, 1, 3, HEIGHT, WIDTH, generator=torch.Generator().manual_seed(degree), dtype=torch.float64)
    function = _projected_render(corrections, gaussians, camera, degree, weights)
    assert torch.autograd.gradcheck(function, (omega, tau), eps=1e-6, atol=1e-5, rtol=1e-4)


@pytest.mark.parametrize("degree", [0, 2])
def test_correction_gradients_match_the_twin_differentiated_through_its_camera(degree):
    """The twin takes the corrected viewmat D V as a differentiable input: autograd through its
    projection and SH is the reference for the corrections' gradients."""
    gaussians = random_scene(60, 8, degree=degree)
    camera = _camera(2)
    weights = torch.randn(1, 3, HEIGHT, WIDTH, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    start = ([0.02, 0.01, -0.03], [0.04, -0.03, 0.02])
    gradients = []
    for path in ("cpu", "twin"):
        corrections = _corrections(camera, *start)
        if path == "cpu":
            images = render(corrections.moved_gaussians(0, gaussians, degree), camera).images
        else:
            settings = RasterSettings(WIDTH, HEIGHT, degree)
            colour, *_ = rasterize_reference(*gaussians.tensors().values(), corrections.corrected(0), INTRINSICS, settings)
            images = colour.permute(2, 0, 1)[None]
        gradients.append(torch.autograd.grad((images * weights).sum(), (corrections.rotations, corrections.translations)))
    for ours, twin in zip(*gradients):
        assert twin.abs().max() > 0
        torch.testing.assert_close(ours, twin, atol=1e-8, rtol=1e-7)


def test_pinned_views_do_not_move():
    camera = Cameras.concatenate([_camera(0), _camera(1)])
    corrections = CameraCorrections(camera.extrinsics, torch.tensor([True, False]))
    gaussians = random_scene(30, 2, degree=0)
    loss = sum(render(corrections.moved_gaussians(v, gaussians, 0), camera[[v]]).images.sum() for v in range(2))
    loss.backward()
    assert not corrections.rotations.grad[0].any() and not corrections.translations.grad[0].any()
    assert corrections.rotations.grad[1].abs().sum() > 0
    torch.testing.assert_close(corrections.corrected_extrinsics(), camera.extrinsics)
