"""Every loss: zero for identical inputs, positive otherwise, finite gradients on black and
saturated inputs."""

import math

import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.losses.distillation import confidence_mask, depth_distillation, iteration_weights, weighted_pose_huber
from lumos3d_cli.losses.feature_networks import load_trunk
from lumos3d_cli.losses.lumos.content import ContentLoss
from lumos3d_cli.losses.lumos.image import image_l1
from lumos3d_cli.losses.lumos.voxel import VoxelStatisticsLoss
from lumos3d_cli.losses.reconstruction import mse_loss
from lumos3d_cli.losses.supervision import pose_supervision, sparse_depth_supervision
from lumos3d_cli.model.pose_encoding import encode_pose

from factories import save_random_trunk

EXTREMES = {"black": 0.0, "saturated": 1.0}


@pytest.fixture(scope="module")
def vgg19(tmp_path_factory):
    path = tmp_path_factory.mktemp("weights") / "vgg19.pth"
    save_random_trunk("vgg19", path)
    return load_trunk("vgg19", path)


def _pair(shape, fill=None, seed=0):
    g = torch.Generator().manual_seed(seed)
    target = torch.rand(shape, generator=g) if fill is None else torch.full(shape, fill)
    render = torch.rand(shape, generator=g).requires_grad_(True)
    return render, target


def _geometry(batch=1, views=2, height=32, width=32):
    g = torch.Generator().manual_seed(3)
    v, u = torch.meshgrid(torch.arange(height) + 0.5, torch.arange(width) + 0.5, indexing="ij")
    depth = 1 + 0.2 * torch.rand(batch, views, height, width, generator=g)
    points = torch.stack([(u - width / 2) / 30 * depth, (v - height / 2) / 30 * depth, depth], dim=-1)
    return points, torch.randn(batch, views, height, width, generator=g), torch.ones(batch)


@pytest.mark.parametrize("loss", [mse_loss, image_l1])
def test_pixel_losses(loss):
    render, target = _pair((2, 3, 8, 8))
    assert loss(target, target).item() == 0 and loss(render, target).item() > 0
    for fill in EXTREMES.values():
        render, target = _pair((2, 3, 8, 8), fill)
        loss(render, target).backward()
        assert torch.isfinite(render.grad).all()


def test_content_loss(vgg19):
    content = ContentLoss(vgg19)
    render, target = _pair((2, 3, 48, 48))
    assert content(target, target).item() == 0 and content(render, target).item() > 0
    for fill in EXTREMES.values():
        render, target = _pair((2, 3, 48, 48), fill)
        content(render, target).backward()
        assert torch.isfinite(render.grad).all() and render.grad.abs().sum() > 0


@pytest.mark.parametrize("with_vgg", [False, True])
def test_voxel_loss(vgg19, with_vgg):
    voxel = VoxelStatisticsLoss(vgg19 if with_vgg else None, voxel_size=0.01)
    points, confidence, scale = _geometry()
    render, target = _pair((1, 2, 3, 32, 32))
    assert voxel(target, target, points, confidence, scale).item() == pytest.approx(0.0, abs=1e-7)
    assert voxel(render, target, points, confidence, scale).item() > 0
    for fill in EXTREMES.values():
        render, target = _pair((1, 2, 3, 32, 32), fill)
        voxel(render, target, points, confidence, scale).backward()
        assert torch.isfinite(render.grad).all()


def test_voxel_loss_matches_statistics_by_hand():
    """One scale, every pixel in its own voxel: the loss is the gap of channel means and stds."""
    voxel = VoxelStatisticsLoss(None, voxel_size=1e-4, weights=(1, 0, 0, 0, 0))
    points, confidence, scale = _geometry(views=1, height=8, width=8)
    render, target = _pair((1, 1, 3, 8, 8))
    a, b = render.detach().reshape(3, -1), target.reshape(3, -1)
    std = lambda x: torch.sqrt(x.var(dim=1, unbiased=False) + 1e-5)  # noqa: E731
    expected = (a.mean(1) - b.mean(1)).abs().mean() + (std(a) - std(b)).abs().mean()
    assert voxel(render, target, points, confidence, scale).item() == pytest.approx(expected.item(), rel=1e-5)


def test_pose_distillation_weights():
    assert iteration_weights(4) == pytest.approx([0.216, 0.36, 0.6, 1.0])
    teacher = [torch.randn(1, 3, 9) for _ in range(4)]
    assert weighted_pose_huber(teacher, teacher).item() == 0
    student = [t.clone().requires_grad_(True) for t in teacher]
    shifted = [s + 0.1 for s in student]
    # Huber(0.1) = 0.5 * 0.01 per element, averaged; weights as above, mean over iterations.
    expected = sum(iteration_weights(4)) * 0.005 / 4
    assert weighted_pose_huber(shifted, teacher).item() == pytest.approx(expected, rel=1e-5)
    weighted_pose_huber(shifted, teacher).backward()
    assert all(torch.isfinite(s.grad).all() for s in student)


def test_depth_distillation_uses_each_views_30th_percentile():
    confidence = torch.arange(2 * 10, dtype=torch.float32).reshape(1, 2, 2, 5)
    mask = confidence_mask(confidence)
    assert mask.sum().item() == 14  # 7 of 10 per view are above the 30th percentile
    assert not mask[0, 0].flatten()[:3].any() and not mask[0, 1].flatten()[:3].any()
    teacher_depth = torch.rand(1, 2, 2, 5) + 1
    rendered = teacher_depth.clone().requires_grad_(True)
    assert depth_distillation(rendered, teacher_depth, confidence).item() == 0
    moved = rendered + 0.5
    assert depth_distillation(moved, teacher_depth, confidence).item() == pytest.approx(0.25)
    for fill in EXTREMES.values():
        depth_distillation(torch.full_like(rendered, fill).requires_grad_(True), teacher_depth, torch.zeros_like(confidence))


def test_ground_truth_supervision():
    extrinsics = torch.eye(4)[:3].repeat(1, 2, 1, 1)
    extrinsics[0, 1, 0, 3] = 0.5
    intrinsics = torch.tensor([[50.0, 0, 28], [0, 50, 21], [0, 0, 1]]).repeat(1, 2, 1, 1)
    target = encode_pose(extrinsics, intrinsics, (42, 56))
    has = torch.tensor([True])
    assert pose_supervision([target] * 4, extrinsics, intrinsics, (42, 56), has).item() == pytest.approx(0, abs=1e-7)
    # VGGT's camera loss: L1 of translation + quaternion + 0.5 x field of view = 0.5 per
    # refinement, refinements weighted 0.6^3, 0.6^2, 0.6, 1 and averaged
    expected = 0.5 * (0.216 + 0.36 + 0.6 + 1.0) / 4
    assert pose_supervision([target + 0.2] * 4, extrinsics, intrinsics, (42, 56), has).item() == pytest.approx(expected)
    rotated = target.clone()
    rotated[..., 3:7] += 0.1  # only the rotation part is off: 0.1 per refinement
    assert pose_supervision([rotated], extrinsics, intrinsics, (42, 56), has).item() == pytest.approx(0.1)
    assert pose_supervision([target + 0.2] * 4, extrinsics, intrinsics, (42, 56), ~has).item() == 0
    sparse = torch.zeros(1, 2, 4, 4)
    sparse[0, 0, 1, 1] = 2.0
    depth = torch.full((1, 2, 4, 4), 2.0, requires_grad=True)
    confidence = torch.full((1, 2, 4, 4), 2.0, requires_grad=True)
    # |error| * confidence - 0.2 * log(confidence), on the one pixel holding a point
    assert sparse_depth_supervision(depth, confidence, sparse).item() == pytest.approx(-0.2 * math.log(2))
    assert sparse_depth_supervision(depth + 1, confidence, sparse).item() == pytest.approx(2 - 0.2 * math.log(2))
    sparse_depth_supervision(depth + 1, confidence, sparse).backward()
    assert confidence.grad[0, 0, 1, 1] == pytest.approx(1 - 0.2 / 2)  # d/dc (c - 0.2 log c)
    assert confidence.grad.abs().sum() == confidence.grad[0, 0, 1, 1].abs()
    no_points = sparse_depth_supervision(depth, confidence, torch.zeros_like(sparse))
    assert no_points.item() == 0 and no_points.requires_grad


def test_trunk_loader_is_strict(tmp_path):
    save_random_trunk("vgg16", tmp_path / "vgg16.pth")
    with pytest.raises(InputError, match=r"vgg16.pth \(torchvision vgg19\): does not fit the model; .*missing keys"):
        load_trunk("vgg19", tmp_path / "vgg16.pth")
    with pytest.raises(InputError, match="weight file not found"):
        load_trunk("vgg19", tmp_path / "missing.pth")
    with pytest.raises(InputError, match="is a folder; give the weight file itself"):  # was "not found"
        load_trunk("vgg19", tmp_path)
