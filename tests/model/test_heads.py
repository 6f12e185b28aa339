import dataclasses

import torch

from lumos3d_cli.model.architectures import ARCHITECTURES
from lumos3d_cli.model.backbone import Aggregator
from lumos3d_cli.model.heads import dpt
from lumos3d_cli.model.heads.camera import CameraHead
from lumos3d_cli.model.heads.dpt import DepthHead
from lumos3d_cli.model.heads.fusion import ResidualConvUnit
from lumos3d_cli.model.heads.gaussian import GaussianHead
from lumos3d_cli.model.heads.uv_embedding import uv_embedding, uv_grid

ARCHITECTURE = ARCHITECTURES["tiny"]


def _tokens(batch: int, frames: int, height: int, width: int, seed: int = 0) -> dict[int, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    patches = (height // ARCHITECTURE.patch_size) * (width // ARCHITECTURE.patch_size)
    shape = (batch, frames, ARCHITECTURE.patch_start_index + patches, 2 * ARCHITECTURE.embed_dim)
    return {layer: torch.randn(shape, generator=generator) for layer in range(ARCHITECTURE.depth)}


def test_uv_embedding_matches_vggt_values():
    # Values printed by VGGT's create_uv_grid / position_grid_to_embed for a 37 x 28 grid of a
    # 518 x 392 image with 256 channels.
    grid = uv_grid(28, 37, 518 / 392, torch.float32, None)
    torch.testing.assert_close(grid[0, 0], torch.tensor([-0.7759, -0.5819]), atol=1e-4, rtol=0)
    torch.testing.assert_close(grid[-1, -1], torch.tensor([0.7759, 0.5819]), atol=1e-4, rtol=0)
    embedding = uv_embedding(28, 37, 256, 518 / 392, torch.float32, None)
    assert embedding.shape == (256, 28, 37)
    torch.testing.assert_close(embedding[:3, 0, 0], torch.tensor([-0.7003, -0.6609, -0.6224]), atol=1e-4, rtol=0)
    torch.testing.assert_close(embedding[64:67, 0, 0], torch.tensor([0.7138, 0.7505, 0.7827]), atol=1e-4, rtol=0)


def test_residual_unit_skip_adds_the_rectified_input():
    unit = ResidualConvUnit(4)
    torch.nn.init.zeros_(unit.conv2.weight)
    torch.nn.init.zeros_(unit.conv2.bias)
    x = torch.randn(2, 4, 5, 5)
    torch.testing.assert_close(unit(x), torch.relu(x))


def test_camera_head_returns_every_refinement_with_non_negative_fov():
    head = CameraHead(ARCHITECTURE).eval()
    encodings = head(_tokens(2, 3, 28, 42)[ARCHITECTURE.depth - 1])
    assert len(encodings) == ARCHITECTURE.camera_iterations == 4
    assert all(e.shape == (2, 3, 9) for e in encodings)
    assert all((e[..., 7:] >= 0).all() for e in encodings)
    assert not torch.equal(encodings[0], encodings[-1])


def test_camera_head_feeds_back_a_detached_estimate():
    head = CameraHead(ARCHITECTURE)
    encodings = head(_tokens(1, 2, 28, 28)[ARCHITECTURE.depth - 1])
    # estimate_k = estimate_0 + sum of updates computed from *detached* estimates, so every
    # iteration's translation and rotation depend on the empty pose token only through estimate_0
    grads = [torch.autograd.grad(e[..., :7].sum(), head.empty_pose_tokens, retain_graph=True)[0] for e in encodings]
    assert grads[0].abs().sum() > 0
    for grad in grads[1:]:
        torch.testing.assert_close(grad, grads[0])


def test_depth_head_outputs_positive_depth_and_confidence_above_one():
    head = DepthHead(ARCHITECTURE).eval()
    images = torch.rand(1, 2, 3, 42, 28)
    depth, confidence = head(_tokens(1, 2, 42, 28), images)
    assert depth.shape == confidence.shape == (1, 2, 42, 28)
    assert (depth > 0).all() and (confidence > 1).all()


def test_frame_chunking_does_not_change_the_result(monkeypatch):
    head = DepthHead(ARCHITECTURE).eval()
    tokens, images = _tokens(1, 5, 28, 28), torch.rand(1, 5, 3, 28, 28)
    with torch.no_grad():
        whole = head(tokens, images)
        monkeypatch.setattr(dpt, "FRAMES_PER_CHUNK", 2)
        chunked = head(tokens, images)
    torch.testing.assert_close(whole[0], chunked[0])
    torch.testing.assert_close(whole[1], chunked[1])


def test_gaussian_head_channels_and_rgb_shortcut():
    architecture = dataclasses.replace(ARCHITECTURE, sh_degree=2)
    head = GaussianHead(architecture).eval()
    tokens = _tokens(1, 2, 28, 56)
    images = torch.rand(1, 2, 3, 28, 56)
    with torch.no_grad():
        raw = head(tokens, images)
        assert raw.shape == (1, 2, 1 + 3 + 4 + 27 + 1, 28, 56)
        # the shortcut makes single pixels of the input matter at full resolution
        changed = images.clone()
        changed[0, 0, :, 10, 30] = 1 - changed[0, 0, :, 10, 30]
        difference = (head(tokens, changed) - raw).abs().sum(dim=2)[0, 0]
    assert difference[10, 30] > 0 and difference[0, 0] == 0


def test_aggregator_layers_shapes():
    aggregator = Aggregator(ARCHITECTURE).eval()
    with torch.no_grad():
        out = aggregator(torch.rand(2, 3, 3, 28, 42), layers=[1, 3])
    assert sorted(out) == [1, 3]
    assert out[3].shape == (2, 3, ARCHITECTURE.patch_start_index + 6, 2 * ARCHITECTURE.embed_dim)
