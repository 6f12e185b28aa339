import logging

import numpy as np
import pytest
import torch

from lumos3d_cli.errors import InputError, NonFiniteError
from lumos3d_cli.model.geometry import unproject_depth
from lumos3d_cli.model.lumos3d import Lumos3DOutput, build_model
from lumos3d_cli.model.pose_encoding import decode_pose


@pytest.fixture(scope="module")
def model():
    return build_model("tiny", seed=0).eval()


def _check(output: Lumos3DOutput, batch: int, views: int, height: int, width: int) -> None:
    """Shapes, finiteness, valid cameras and consistent Gaussian counts."""
    assert output.pose_enc.shape == (batch, views, 9) and len(output.pose_enc_list) == 4
    assert output.extrinsics.shape == (batch, views, 3, 4) and output.intrinsics.shape == (batch, views, 3, 3)
    assert output.depth.shape == output.depth_conf.shape == output.pixel_confidence.shape == (batch, views, height, width)
    assert output.world_points.shape == (batch, views, height, width, 3)
    for tensor in (output.pose_enc, output.extrinsics, output.intrinsics, output.depth, output.depth_conf, output.world_points):
        assert torch.isfinite(tensor).all()
    assert (output.depth > 0).all() and (output.depth_conf >= 1).all()
    for scene in range(batch):
        output.cameras(scene).require_valid()
        counts = output.counts[scene]
        assert counts.pixels == views * height * width == len(output.pixel_gaussians[scene])
        assert 0 < counts.voxels <= counts.pixels and len(output.gaussians[scene]) == counts.kept
        for gaussians in (output.gaussians[scene], output.pixel_gaussians[scene]):
            assert all(torch.isfinite(t).all() for t in gaussians.tensors().values())
            assert (gaussians.scales > 0).all()
            torch.testing.assert_close(gaussians.quats.norm(dim=1), torch.ones(len(gaussians)))


def test_outputs_are_consistent(model):
    images = torch.rand(2, 3, 3, 42, 56, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        output = model(images)
    _check(output, 2, 3, 42, 56)
    assert torch.equal(output.pose_enc, output.pose_enc_list[-1])
    extrinsics, intrinsics = decode_pose(output.pose_enc, (42, 56))
    torch.testing.assert_close(output.extrinsics, extrinsics)
    torch.testing.assert_close(output.intrinsics, intrinsics)
    torch.testing.assert_close(output.world_points, unproject_depth(output.depth, extrinsics, intrinsics))
    torch.testing.assert_close(output.pixel_gaussians[1].means, output.world_points[1].reshape(-1, 3))
    torch.testing.assert_close(output.scene_scale, output.depth.flatten(1).median(dim=1).values)
    assert output.image_size == (56, 42) and output.cameras(0).sizes == [(56, 42)] * 3
    assert output.pixel_gaussians[0].sh_degree == model.architecture.sh_degree


def test_scenes_of_a_batch_are_independent(model):
    images = torch.rand(2, 2, 3, 28, 42, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        both = model(images)
        second = model(images[1:])
    torch.testing.assert_close(both.pose_enc[1:], second.pose_enc, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(both.depth[1:], second.depth, atol=1e-5, rtol=1e-5)
    assert both.counts[1] == second.counts[0]


@pytest.mark.parametrize(
    ("views", "height", "width", "fill"),
    [
        (1, 28, 28, None),  # one view, the smallest image (2 x 2 patches)
        (2, 28, 70, None),  # non-square, wide
        (2, 84, 28, None),  # non-square, tall
        (3, 42, 42, 0.0),  # all black
        (3, 42, 42, 1.0),  # saturated
        (32, 28, 28, None),  # many views
    ],
)
def test_extreme_inputs_give_finite_valid_outputs(model, views, height, width, fill):
    images = torch.rand(1, views, 3, height, width, generator=torch.Generator().manual_seed(3))
    if fill is not None:
        images.fill_(fill)
    with torch.no_grad():
        _check(model(images), 1, views, height, width)


def test_bf16_autocast_gives_finite_valid_outputs_close_to_float32(model):
    images = torch.rand(1, 3, 3, 42, 42, generator=torch.Generator().manual_seed(4))
    with torch.no_grad():
        reference = model(images)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            output = model(images)
    _check(output, 1, 3, 42, 42)
    assert output.depth.dtype == torch.float32 and output.pose_enc.dtype == torch.float32
    torch.testing.assert_close(output.pose_enc, reference.pose_enc, atol=0.1, rtol=0.1)


def test_gradients_reach_every_trainable_parameter():
    model = build_model("tiny", seed=1).train()
    output = model(torch.rand(1, 2, 3, 28, 28, generator=torch.Generator().manual_seed(5)))
    gaussians = output.gaussians[0]
    loss = (
        sum(e.square().mean() for e in output.pose_enc_list)
        + output.depth.mean() + output.depth_conf.mean()
        + sum(t.square().mean() for t in gaussians.tensors().values())
    )
    loss.backward()
    missing = [n for n, p in model.named_parameters() if p.requires_grad and (p.grad is None or not p.grad.abs().sum() > 0)]
    assert missing == []


def test_bad_inputs_are_refused_with_a_clear_message(model):
    with pytest.raises(InputError, match="multiple of the patch size 14"):
        model(torch.rand(1, 1, 3, 30, 28))
    with pytest.raises(InputError, match=r"\[B, V, 3, H, W\]"):
        model(torch.rand(1, 3, 28, 28))
    images = torch.rand(1, 1, 3, 28, 28)
    images[0, 0, 0, 0, 0] = float("nan")
    with pytest.raises(NonFiniteError):
        model(images)
    # an empty batch or view list failed deep inside (a reshape); 8-bit codes ran as a white frame
    for empty in (torch.rand(0, 1, 3, 28, 28), torch.rand(1, 0, 3, 28, 28)):
        with pytest.raises(InputError, match="with B and V at least 1"):
            model(empty)
    with pytest.raises(InputError, match=r"model input images: values from .* to .*; give sRGB in \[0, 1\] \(8-bit codes"):
        model(torch.rand(1, 1, 3, 28, 28) * 255)


def test_fusion_settings_are_checked_by_name(model):
    images = torch.rand(1, 2, 3, 28, 28, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        prediction = model.predict(images)
        for size in (0.0, -1.0, float("nan"), float("inf")):  # a size of 0 or NaN fused the scene into one Gaussian
            with pytest.raises(InputError, match="^voxel_size .*give a positive number"):
                model.assemble(prediction, voxel_size=size)
        for mask in (torch.tensor([1, 0]), torch.tensor([True]), torch.tensor([True, False, True]), [True, False]):
            with pytest.raises(InputError, match=r"^fuse_views must be a bool tensor of shape \[2\]"):
                model.assemble(prediction, fuse_views=mask)
        with pytest.raises(InputError, match=r"^fuse_pixels must be a bool tensor of shape \[1, 2, 28, 28\]"):
            model.assemble(prediction, fuse_pixels=torch.ones(2, 28, 28, dtype=torch.bool))
        assert model.assemble(prediction, fuse_views=torch.tensor([True, False])).counts[0].pixels == 28 * 28
        assert model.assemble(prediction, voxel_size=np.float32(0.002)).counts[0].voxels > 0  # numpy numbers are numbers


@pytest.mark.parametrize("dtype", [torch.float64, torch.float16, torch.bfloat16])
def test_images_of_any_floating_type_run_in_the_weights_type(model, dtype):
    images = torch.rand(1, 2, 3, 28, 28, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        expected = model(images).depth
        got = model(images.to(dtype)).depth
    assert got.dtype == torch.float32
    # the images rounded to the type's precision (bf16: 8 bits) move the depth a little
    torch.testing.assert_close(got, expected, rtol=0.05 if dtype == torch.bfloat16 else 0.01, atol=0)
    with pytest.raises(InputError, match="torch.uint8; give floating-point images"):
        model((images * 255).to(torch.uint8))


def test_prepare_then_forward_any_image_size(model):
    prepared = model.prepare(torch.rand(2, 3, 37, 51))
    assert prepared.network_size == (224, 168)
    with torch.no_grad():
        output = model(prepared.images[None])
    original = prepared.intrinsics_to_original(output.intrinsics[0])
    torch.testing.assert_close(original[:, :2, 2], torch.tensor([[51 / 2, 37 / 2]] * 2))


def test_build_model_says_its_weights_are_random(caplog):
    with caplog.at_level(logging.INFO, logger="lumos3d_cli.model.lumos3d"):
        model = build_model("tiny", seed=3)
    assert "random weights" in caplog.text
    assert model.provenance == {"weights": "random", "seed": 3}
    again = build_model("tiny", seed=3)
    assert all(torch.equal(a, b) for a, b in zip(model.state_dict().values(), again.state_dict().values()))


@pytest.mark.slow
def test_thirty_two_views_at_the_tiny_architecture_resolution(model):
    size = model.architecture.image_size
    with torch.no_grad():
        _check(model(torch.rand(1, 32, 3, size, size)), 1, 32, size, size)


def test_fusion_does_not_depend_on_the_world_unit(model):
    generator = torch.Generator().manual_seed(6)
    views, height, width = 2, 14, 14
    points = torch.rand(views, height, width, 3, generator=generator, dtype=torch.float64) * 0.05
    params = torch.randn(views, height, width, model.architecture.gaussian_channels - 1, generator=generator, dtype=torch.float64)
    confidence = torch.randn(views, height, width, generator=generator, dtype=torch.float64)
    scale = torch.tensor(0.8, dtype=torch.float64)
    unit = 1000.0  # the same scene in millimetres instead of metres
    pixels, fused, counts = model.fuse_scene(points, params, confidence, scale)
    pixels_mm, fused_mm, counts_mm = model.fuse_scene(points * unit, params, confidence, scale * unit)
    assert counts == counts_mm and counts.voxels < counts.pixels
    for a, b in ((pixels, pixels_mm), (fused, fused_mm)):
        torch.testing.assert_close(b.means, a.means * unit)
        torch.testing.assert_close(b.scales, a.scales * unit)
        for name in ("quats", "opacities", "sh"):
            torch.testing.assert_close(getattr(b, name), getattr(a, name))


def test_fuse_views_keeps_only_the_selected_views(model):
    images = torch.rand(1, 3, 3, 28, 42, generator=torch.Generator().manual_seed(5))
    only_first = torch.tensor([True, False, False])
    with torch.no_grad():
        full = model(images)
        held = model(images, fuse_views=only_first)
    # The cameras and depth still see every view; only the fused scene is restricted.
    torch.testing.assert_close(held.depth, full.depth)
    assert held.counts[0].pixels == 28 * 42 < full.counts[0].pixels
    torch.testing.assert_close(held.pixel_gaussians[0].means, full.world_points[0, 0].reshape(-1, 3))
    with pytest.raises(ValueError, match="selects no view"):
        with torch.no_grad():
            model(images, fuse_views=torch.zeros(3, dtype=torch.bool))


def test_voxel_size_override_sets_the_fusion_grain(model):
    images = torch.rand(1, 2, 3, 28, 42, generator=torch.Generator().manual_seed(6))
    with torch.no_grad():
        fine = model(images, voxel_size=1e-9)
        default = model(images)
        coarse = model(images, voxel_size=1e9)
    # Distinct points never share a voxel of a vanishing size; one huge voxel holds them all.
    assert fine.counts[0].voxels == fine.counts[0].pixels
    assert coarse.counts[0].voxels == 1
    assert coarse.counts[0].voxels <= default.counts[0].voxels <= fine.counts[0].voxels


def test_footprint_voxels_through_assemble(model):
    images = torch.rand(1, 3, 3, 28, 42, generator=torch.Generator().manual_seed(8))
    with torch.no_grad():
        prediction = model.predict(images)
        fixed = model.assemble(prediction)
        explicit = model.assemble(prediction, voxel_size=model.architecture.voxel_size)
        fine = model.assemble(prediction, footprint_scale=1e-9)
        coarse = model.assemble(prediction, footprint_scale=1e9)
        held = model.assemble(prediction, footprint_scale=1.0, fuse_views=torch.tensor([True, False, True]))
    # Without footprint_scale nothing changes: the architecture's one voxel size, as in training.
    assert fixed.counts == explicit.counts and torch.equal(fixed.gaussians[0].means, explicit.gaussians[0].means)
    assert fine.counts[0].voxels == fine.counts[0].pixels
    assert coarse.counts[0].voxels < fixed.counts[0].voxels
    assert held.counts[0].pixels == 2 * 28 * 42
    for output in (fine, coarse, held):
        _check_fused(output)
    with pytest.raises(ValueError, match="not both"):
        model.assemble(prediction, voxel_size=0.01, footprint_scale=1.0)


def _check_fused(output: Lumos3DOutput) -> None:
    gaussians = output.gaussians[0]
    assert len(gaussians) == output.counts[0].kept > 0
    assert all(torch.isfinite(t).all() for t in gaussians.tensors().values()) and (gaussians.scales > 0).all()
    torch.testing.assert_close(gaussians.quats.norm(dim=1), torch.ones(len(gaussians)))


def test_rendering_the_model_output_reaches_the_weights(model):
    """The training path: forward -> fused Gaussians -> rasterizer -> loss -> every head's weights."""
    from lumos3d_cli.render.render import render

    images = torch.rand(1, 2, 3, 28, 42, generator=torch.Generator().manual_seed(7))
    trained = build_model("tiny", seed=0)
    output = trained(images)
    rendered = render(output.gaussians[0], output.cameras(0))
    assert rendered.images.shape == (2, 3, 28, 42) and torch.isfinite(rendered.images).all()
    assert (rendered.alphas > 0.5).float().mean() > 0.5  # the predicted cameras see their own Gaussians
    (rendered.images - images[0]).square().mean().backward()
    head = trained.gaussian_head
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in head.parameters())
    assert all(torch.isfinite(p.grad).all() for p in trained.parameters() if p.grad is not None)


def test_rendering_gradients_do_not_reach_the_camera_head():
    """Gaussian centres use stop-gradient cameras: only camera losses train the camera head."""
    model = build_model("tiny", seed=0)
    images = torch.rand(1, 2, 3, 28, 42, generator=torch.Generator().manual_seed(8))
    output = model(images)
    output.gaussians[0].means.sum().backward()
    assert all(p.grad is None or not p.grad.any() for p in model.camera_head.parameters())
    assert any(p.grad is not None and p.grad.any() for p in model.depth_head.parameters())
    model.zero_grad()
    model(images).pose_enc.sum().backward()
    assert any(p.grad is not None and p.grad.any() for p in model.camera_head.parameters())
