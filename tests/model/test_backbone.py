import dataclasses

import torch

from lumos3d_cli.model.architectures import ARCHITECTURES, PatchEmbedConfig
from lumos3d_cli.model.backbone import Aggregator
from lumos3d_cli.model.layers.vision_transformer import DinoVisionTransformer

ARCHITECTURE = ARCHITECTURES["tiny"]


def test_views_after_the_first_are_interchangeable_but_the_first_is_special():
    torch.manual_seed(0)
    aggregator = Aggregator(ARCHITECTURE).eval()
    with torch.no_grad():
        aggregator.camera_token.normal_()  # make the first-frame slot clearly different
        images = torch.rand(1, 4, 3, 28, 42)
        out = aggregator(images, layers=[ARCHITECTURE.depth - 1])[ARCHITECTURE.depth - 1]
        order = [0, 3, 1, 2]
        permuted = aggregator(images[:, order], layers=[ARCHITECTURE.depth - 1])[ARCHITECTURE.depth - 1]
        torch.testing.assert_close(permuted, out[:, order], atol=1e-5, rtol=1e-5)
        swapped = aggregator(images[:, [1, 0, 2, 3]], layers=[ARCHITECTURE.depth - 1])[ARCHITECTURE.depth - 1]
    assert not torch.allclose(swapped[:, 1], out[:, 0], atol=1e-3)


def test_frame_half_of_layer_zero_sees_only_its_own_frame():
    aggregator = Aggregator(ARCHITECTURE).eval()
    images = torch.rand(1, 3, 3, 28, 28)
    changed = images.clone()
    changed[:, 2] = 1 - changed[:, 2]
    with torch.no_grad():
        a = aggregator(images, layers=[0])[0]
        b = aggregator(changed, layers=[0])[0]
    channels = ARCHITECTURE.embed_dim
    torch.testing.assert_close(a[:, :2, :, :channels], b[:, :2, :, :channels])  # frame attention: per view
    assert not torch.allclose(a[:, :2, :, channels:], b[:, :2, :, channels:])  # global attention: across views


def test_dino_position_embedding_is_kept_at_its_grid_and_resampled_elsewhere():
    vit = DinoVisionTransformer(image_size=56, patch_size=14, embed_dim=32, depth=1, num_heads=2, mlp_ratio=4.0, num_register_tokens=4)
    assert vit.position_embedding(4, 4, torch.float32) is vit.pos_embed
    resampled = vit.position_embedding(2, 6, torch.float32)
    assert resampled.shape == (1, 1 + 12, 32)
    torch.testing.assert_close(resampled[:, 0], vit.pos_embed[:, 0])
    assert vit(torch.rand(3, 3, 28, 84)).shape == (3, 12, 32)


def test_gradient_checkpointing_gives_the_same_gradients():
    architecture = dataclasses.replace(ARCHITECTURE, patch_embed=PatchEmbedConfig(kind="dinov2", depth=1, num_heads=4), image_size=56)
    torch.manual_seed(1)
    aggregator = Aggregator(architecture)
    images = torch.rand(1, 2, 3, 28, 28)
    grads = []
    for enabled in (False, True):
        aggregator.zero_grad()
        aggregator.set_gradient_checkpointing(enabled)
        aggregator(images, layers=[architecture.depth - 1])[architecture.depth - 1].square().mean().backward()
        grads.append([p.grad.clone() for p in aggregator.parameters() if p.grad is not None])
    assert len(grads[0]) == len(grads[1]) > 0
    for a, b in zip(*grads):
        torch.testing.assert_close(a, b)
