import dataclasses
import json

import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.model.architectures import ARCHITECTURES, Architecture, get_architecture
from lumos3d_cli.model.lumos3d import Lumos3D
from lumos3d_cli.typed_config import from_dict, to_dict


def _meta_model(architecture: Architecture) -> Lumos3D:
    with torch.device("meta"):
        return Lumos3D(architecture)


def _counts(model: Lumos3D) -> dict[str, tuple[int, int]]:
    """{module: (tensors, numbers)} of the state dict."""
    counts: dict[str, list[int]] = {}
    for key, tensor in model.state_dict().items():
        entry = counts.setdefault(key.split(".")[0], [0, 0])
        entry[0] += 1
        entry[1] += tensor.numel()
    return {name: tuple(value) for name, value in counts.items()}


def test_vggt_1b_has_the_official_key_counts_and_sizes():
    counts = _counts(_meta_model(ARCHITECTURES["vggt-1b"]))
    # Numbers of the official VGGT-1B state dict (aggregator, camera and depth heads) and the
    # key counts of AnySplat's released model.safetensors (its Gaussian head at SH degree 4).
    assert counts["aggregator"] == (1210, 909_112_320)
    assert counts["camera_head"] == (69, 216_174_610)
    assert counts["depth_head"] == (62, 32_654_562)
    assert counts["gaussian_head"][0] == 64


def test_vggt_1b_key_names_and_shapes_spot_checks():
    state = _meta_model(ARCHITECTURES["vggt-1b"]).state_dict()
    expected = {
        "aggregator.camera_token": (1, 2, 1, 1024),
        "aggregator.register_token": (1, 2, 4, 1024),
        "aggregator.patch_embed.pos_embed": (1, 1370, 1024),
        "aggregator.patch_embed.mask_token": (1, 1024),
        "aggregator.patch_embed.patch_embed.proj.weight": (1024, 3, 14, 14),
        "aggregator.patch_embed.blocks.23.ls2.gamma": (1024,),
        "aggregator.frame_blocks.23.attn.q_norm.weight": (64,),
        "aggregator.global_blocks.0.attn.qkv.weight": (3072, 1024),
        "camera_head.poseLN_modulation.1.weight": (6144, 2048),
        "camera_head.trunk.3.mlp.fc1.weight": (8192, 2048),
        "camera_head.pose_branch.fc2.weight": (9, 1024),
        "camera_head.empty_pose_tokens": (1, 1, 9),
        "depth_head.resize_layers.0.weight": (256, 256, 4, 4),
        "depth_head.resize_layers.3.weight": (1024, 1024, 3, 3),
        "depth_head.scratch.layer4_rn.weight": (256, 1024, 3, 3),
        "depth_head.scratch.output_conv2.2.weight": (2, 32, 1, 1),
        "gaussian_head.scratch.output_conv2.0.weight": (128, 128, 3, 3),
        "gaussian_head.scratch.output_conv2.2.weight": (84, 128, 1, 1),
        "gaussian_head.input_merger.0.weight": (128, 3, 7, 7),
    }
    for key, shape in expected.items():
        assert tuple(state[key].shape) == shape, key
    assert not any(k.startswith("aggregator.patch_embed.blocks.0.attn.q_norm") for k in state)  # DINO: no QK-norm
    assert "depth_head.scratch.refinenet4.resConfUnit1.conv1.weight" not in state
    assert "depth_head.resize_layers.2.weight" not in state
    assert not list(_meta_model(ARCHITECTURES["vggt-1b"]).buffers())  # nothing but parameters is stored


@pytest.mark.parametrize("name", sorted(ARCHITECTURES))
def test_every_architecture_builds_and_round_trips_through_its_dict(name):
    architecture = get_architecture(name)
    assert from_dict(Architecture, json.loads(json.dumps(to_dict(architecture)))) == architecture
    model = _meta_model(architecture)
    assert sum(p.numel() for p in model.parameters()) > 0
    assert architecture.gaussian_channels == 9 + 3 * (architecture.sh_degree + 1) ** 2


def test_tiny_is_small():
    parameters = sum(p.numel() for p in _meta_model(ARCHITECTURES["tiny"]).parameters())
    assert 1_000_000 < parameters < 10_000_000


def test_invalid_architectures_and_names_are_refused():
    with pytest.raises(ValueError, match="divisible"):
        dataclasses.replace(ARCHITECTURES["tiny"], num_heads=5)
    with pytest.raises(ValueError, match="intermediate_layers"):
        dataclasses.replace(ARCHITECTURES["tiny"], intermediate_layers=(0, 1, 2, 9))
    with pytest.raises(InputError, match="tiny"):
        get_architecture("huge")
    with pytest.raises(InputError, match="unknown config key 'colour'"):
        from_dict(Architecture, {**to_dict(ARCHITECTURES["tiny"]), "colour": 3})
