"""Degenerate and extreme inputs: no NaN, sensible output, finite gradients."""

import pytest
import torch

from lumos3d_cli.errors import InputError, NonFiniteError
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.render.render import render

from factories import camera_at_origin, random_scene


def _render_with_grad(gaussians, cameras, **options):
    leaves = {name: t.clone().requires_grad_(True) for name, t in gaussians.tensors().items()}
    output = render(Gaussians(**leaves), cameras, **options)
    (output.images.sum() + output.alphas.sum() + output.depths.sum()).backward()
    for name, leaf in leaves.items():
        assert torch.isfinite(leaf.grad).all(), name
    for tensor in (output.images, output.alphas, output.depths):
        assert torch.isfinite(tensor).all()
    return output, {name: leaf.grad for name, leaf in leaves.items()}


def test_no_gaussians():
    empty = random_scene(0, 0, degree=1, dtype=torch.float32)
    output, _ = _render_with_grad(empty, camera_at_origin(16, 12), background=(0.1, 0.2, 0.3))
    assert output.images.shape == (1, 3, 12, 16) and output.radii.shape == (1, 0, 2)
    torch.testing.assert_close(output.images[0, :, 5, 5], torch.tensor([0.1, 0.2, 0.3]))


def test_everything_outside_or_behind():
    gaussians = random_scene(20, 1, dtype=torch.float32)
    gaussians.means[:10, 2] = -gaussians.means[:10, 2]  # behind the camera
    gaussians.means[10:, 0] += 100.0  # far to the right
    output, grads = _render_with_grad(gaussians, camera_at_origin(16, 12))
    assert not output.visible.any() and output.alphas.abs().max() == 0
    assert all(g.abs().max() == 0 for g in grads.values())


def test_gaussian_at_the_near_plane():
    gaussians = random_scene(3, 2, dtype=torch.float32)
    gaussians.means[:] = torch.tensor([[0.0, 0.0, 0.0101], [0.0, 0.0, 0.0099], [0.0, 0.0, 0.011]])  # near = 0.01
    gaussians.scales[:] = 0.001
    output, _ = _render_with_grad(gaussians, camera_at_origin(16, 12))
    assert output.visible[0].tolist() == [True, False, True]


@pytest.mark.parametrize("scale", [0.0, 1e4])
def test_zero_and_huge_scales(scale):
    gaussians = random_scene(8, 3, dtype=torch.float32)
    gaussians.scales[:4] = scale
    output, _ = _render_with_grad(gaussians, camera_at_origin(32, 24))
    assert output.visible[0, :4].all()  # a zero scale still draws a dilated dot; a huge one covers the image
    if scale > 1:
        assert output.alphas.min() > 0.9


@pytest.mark.parametrize("scale", [1e8, 1e12])
def test_the_kernel_and_its_twin_agree_on_gaussians_far_larger_than_the_scene(scale):
    """In float32 the twin's 2D determinant overflowed: it drew nothing (alpha 0) where the
    kernel covered the image (0.9997), and its gradients were not finite from std 1e12."""
    gaussians = random_scene(4, 0, dtype=torch.float32)
    gaussians.scales[0], gaussians.opacities[0] = scale, 0.95
    camera = camera_at_origin(32, 24)
    kernel, _ = _render_with_grad(gaussians, camera, backend="cpu")
    twin, _ = _render_with_grad(gaussians, camera, backend="reference")
    assert kernel.alphas.min() > 0.9
    torch.testing.assert_close(twin.alphas, kernel.alphas, atol=1e-5, rtol=0)
    torch.testing.assert_close(twin.images, kernel.images, atol=1e-5, rtol=0)


@pytest.mark.parametrize("length", [1e18, 1e19])
def test_a_needle_longer_than_an_int64_of_pixels_is_drawn_by_the_kernel(length):
    """The kernel rounded the projected radius up to an int64 before capping it: past 9.2e18 px it
    wrapped negative and the needle was culled (alpha 0) where the twin drew it across the image."""
    gaussians = Gaussians(torch.tensor([[0.0, 0.0, 2.0]]), torch.tensor([[1.0, 0.0, 0.0, 0.0]]),
                          torch.tensor([[length, 0.05, 0.05]]), torch.tensor([0.9]), torch.zeros(1, 1, 3))
    camera = camera_at_origin(32, 32)
    kernel = render(gaussians, camera, backend="cpu")
    twin = render(gaussians, camera, backend="reference")
    assert kernel.alphas.sum() > 30  # a line across the 32-px image
    torch.testing.assert_close(kernel.alphas, twin.alphas, atol=1e-5, rtol=0)
    assert kernel.radii.tolist() == twin.radii.tolist() and kernel.radii[0, 0, 0] == 2**30


def test_values_outside_the_activated_ranges_are_refused():
    """An opacity of 2 rendered (the kernel and its twin differing) and was saved as 1; a negative
    scale rendered as its size and was saved as 1e-30; a background of 2 was composited."""
    from lumos3d_cli.io.ply import write_ply

    camera = camera_at_origin(16, 12)
    for name, value, message in (("opacities", 2.0, r"gaussians.opacities: 1 value\(s\) outside the activated range \(2"),
                                 ("scales", -0.1, r"gaussians.scales: 1 value\(s\) outside the activated range \(-0.1")):
        gaussians = random_scene(5, 0, dtype=torch.float32)
        getattr(gaussians, name).view(-1)[0] = value
        with pytest.raises(ValueError, match=message):
            render(gaussians, camera)
        with pytest.raises(ValueError, match=message.replace("gaussians", "scene to save")):
            write_ply("unused.ply", gaussians)
    with pytest.raises(ValueError, match=r"background \[2.0, 0.0, 0.0\]: an RGB colour in \[0, 1\]"):
        render(random_scene(5, 0, dtype=torch.float32), camera, background=(2.0, 0.0, 0.0))


def test_zero_and_unnormalised_quaternions():
    gaussians = random_scene(6, 4, dtype=torch.float32)
    reference = render(gaussians, camera_at_origin(32, 24))
    scaled = Gaussians(gaussians.means, gaussians.quats * 37.0, gaussians.scales, gaussians.opacities, gaussians.sh)
    torch.testing.assert_close(render(scaled, camera_at_origin(32, 24)).images, reference.images, atol=1e-6, rtol=0)
    gaussians.quats[0] = 0.0  # treated as identity
    _, grads = _render_with_grad(gaussians, camera_at_origin(32, 24))
    assert grads["quats"][0].abs().max() == 0


def test_opacity_zero_and_one():
    gaussians = random_scene(6, 5, dtype=torch.float32)
    gaussians.opacities[:3] = 0.0
    gaussians.opacities[3:] = 1.0
    output, _ = _render_with_grad(gaussians, camera_at_origin(32, 24))
    assert not output.visible[0, :3].any() and output.visible[0, 3:].all()
    assert output.alphas.max() <= 1.0


@pytest.mark.parametrize("size", [(1, 1), (2048, 2048)])
def test_tiny_and_large_images(size):
    width, height = size
    gaussians = random_scene(50, 6, dtype=torch.float32, spread=0.2)
    output, _ = _render_with_grad(gaussians, camera_at_origin(width, height))
    assert output.images.shape == (1, 3, height, width)
    assert output.alphas.max() > 0


def test_scene_far_away_renders_like_a_small_near_scene():
    """Perspective is scale-invariant: scaling the scene about the camera by 1e5 (and its
    Gaussians with it) must give the same image."""
    near = random_scene(40, 7, dtype=torch.float32)
    far = Gaussians(near.means * 1e5, near.quats, near.scales * 1e5, near.opacities, near.sh)
    cameras = camera_at_origin(48, 32)
    output_near = render(near, cameras)
    output_far, _ = _render_with_grad(far, cameras)
    torch.testing.assert_close(output_far.images, output_near.images, atol=1e-4, rtol=0)
    torch.testing.assert_close(output_far.depths, output_near.depths * 1e5, rtol=1e-4, atol=0)


@pytest.mark.parametrize("name", ["means", "quats", "scales", "opacities", "sh"])
def test_nan_inputs_are_named(name):
    gaussians = random_scene(5, 8, dtype=torch.float32)
    getattr(gaussians, name).view(-1)[[0, 2]] = float("nan")
    with pytest.raises(NonFiniteError, match=rf"gaussians\.{name}: 2 of \d+ values are NaN or Inf"):
        render(gaussians, camera_at_origin(16, 12))


def test_nan_camera_is_named():
    cameras = camera_at_origin(16, 12)
    cameras.extrinsics[0, 0, 3] = float("inf")
    with pytest.raises(NonFiniteError, match=r"cameras\.extrinsics: 1 of 12"):
        render(random_scene(3, 9, dtype=torch.float32), cameras)


@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_the_kernel_and_its_twin_read_a_huge_float32_quaternion_as_its_rotation(backend):
    camera = camera_at_origin(64, 48)

    def one(quat):
        return Gaussians(torch.tensor([[0.0, 0.0, 5.0]]), torch.tensor([quat]), torch.tensor([[0.3, 0.05, 0.05]]),
                         torch.tensor([0.9]), torch.ones(1, 1, 3))

    turned = render(one([0.5, 0.5, 0.5, 0.5]), camera, backend=backend).alphas
    torch.testing.assert_close(render(one([1e20] * 4), camera, backend=backend).alphas, turned)
    assert float((render(one([1.0, 0.0, 0.0, 0.0]), camera, backend=backend).alphas - turned).abs().max()) > 0.1


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_half_precision_gaussians_render_in_float32_with_their_gradients(dtype):
    gaussians = random_scene(30, 1, dtype=torch.float32)
    expected = render(gaussians.map(lambda t: t.to(dtype).float()), camera_at_origin(16, 12)).images
    leaves = {name: t.to(dtype).requires_grad_(True) for name, t in gaussians.tensors().items()}
    output = render(Gaussians(**leaves), camera_at_origin(16, 12))
    assert output.images.dtype == torch.float32
    torch.testing.assert_close(output.images, expected)  # the same values as the Gaussians cast by hand
    output.images.sum().backward()
    assert all(leaf.grad.dtype == dtype and torch.isfinite(leaf.grad.float()).all() for leaf in leaves.values())


def test_cameras_that_cannot_render_are_refused_by_name():
    gaussians = random_scene(5, 0, dtype=torch.float32)
    camera = camera_at_origin(16, 12)
    for focal in (0.0, -50.0):
        bad = camera_at_origin(16, 12)
        bad.intrinsics[0, 0, 0] = focal
        with pytest.raises(ValueError, match="^cameras.intrinsics: the focal lengths must be positive"):
            render(gaussians, bad)
    with pytest.raises(ValueError, match="^cameras: no camera to render from"):
        render(gaussians, camera[[]])
    with pytest.raises(ValueError, match=r"^background must be one RGB colour \[3\], got shape \(2,\)"):
        render(gaussians, camera, background=(0.5, 0.5))
    # 100000 px a side was a MemoryError for 112 GiB of buffers, after the projection
    with pytest.raises(InputError, match=r"^cameras: images of 100000x16 pixels; render at 1 to 16384 pixels a side"):
        render(gaussians, camera_at_origin(100000, 16))


def test_sh_beyond_the_supported_degree_is_refused_when_the_gaussians_are_made():
    with pytest.raises(ValueError, match="36 coefficients per channel \\(SH degree 5\\); degrees 0 to 4"):
        Gaussians(torch.zeros(1, 3), torch.tensor([[1.0, 0, 0, 0]]), torch.ones(1, 3), torch.ones(1), torch.zeros(1, 36, 3))


@pytest.mark.parametrize("eps2d", [-0.1, float("nan"), float("inf")])
def test_a_dilation_that_is_not_finite_and_non_negative_is_refused(eps2d):
    """eps2d NaN rendered black from both backends without a word; Inf gave NaN images in the twin."""
    from lumos3d_cli.render.settings import RasterSettings

    with pytest.raises(ValueError, match="eps2d=.* must be finite and >= 0"):
        RasterSettings(16, 12, 0, eps2d=eps2d)


def test_integer_gaussians_and_a_missing_gsplat_are_named():
    """int64 Gaussians rendered on the CPU kernel but failed inside the twin's matmul; backend
    'gsplat' without gsplat was a bare ModuleNotFoundError."""
    from lumos3d_cli.render.gsplat_backend import gsplat_available

    gaussians = random_scene(3, 0, dtype=torch.float32)
    integer = Gaussians(gaussians.means.round().long(), gaussians.quats, gaussians.scales, gaussians.opacities, gaussians.sh)
    for backend in ("cpu", "reference"):
        with pytest.raises(ValueError, match="Gaussians of dtype .*torch.int64.*: give floating-point tensors"):
            render(integer, camera_at_origin(16, 12), backend=backend)
    if not gsplat_available():
        with pytest.raises(ValueError, match="backend 'gsplat': gsplat is not installed"):
            render(gaussians, camera_at_origin(16, 12), backend="gsplat")
