import dataclasses
import math

import pytest
import torch
import torch.nn.functional as F

from lumos3d_cli.model.architectures import ARCHITECTURES
from lumos3d_cli.model.gaussian_adapter import activate_gaussians, sh_degree_weights, split_confidence

ARCHITECTURE = dataclasses.replace(ARCHITECTURES["tiny"], sh_degree=1)


def _raw(n: int = 4) -> torch.Tensor:
    return torch.randn(n, ARCHITECTURE.gaussian_channels, generator=torch.Generator().manual_seed(0))


def test_channel_layout_and_activations():
    raw = _raw()
    raw[0, 0] = 2.0  # opacity logit
    raw[0, 1:4] = torch.tensor([0.0, 1000.0, -1e4])  # scale: softplus(0), clamped max, clamped min
    raw[0, 4:8] = torch.tensor([0.0, 0.0, 3.0, 4.0])  # xyzw, length 5
    raw[0, 8:20] = torch.arange(12.0)  # SH colour-major: R k0..3, G k0..3, B k0..3
    params, confidence = split_confidence(raw)
    assert params.shape == (4, 20) and torch.equal(confidence, raw[:, -1])
    scale = torch.tensor(2.0)
    gaussians = activate_gaussians(torch.zeros(4, 3), params, scale, ARCHITECTURE)
    torch.testing.assert_close(gaussians.opacities[0], torch.sigmoid(torch.tensor(2.0)))
    expected_scale = torch.tensor([ARCHITECTURE.gaussian_scale_base * math.log(2.0), ARCHITECTURE.gaussian_scale_max, ARCHITECTURE.gaussian_scale_min]) * 2.0
    torch.testing.assert_close(gaussians.scales[0], expected_scale)
    torch.testing.assert_close(gaussians.quats[0], torch.tensor([0.8, 0.0, 0.0, 0.6]))  # wxyz
    weights = torch.tensor([1.0, 0.025, 0.025, 0.025])
    torch.testing.assert_close(gaussians.sh[0, :, 0], torch.arange(4.0) * weights)  # red
    torch.testing.assert_close(gaussians.sh[0, :, 2], torch.arange(8.0, 12.0) * weights)  # blue
    assert gaussians.sh_degree == 1


def test_zero_quaternion_becomes_identity():
    raw = _raw(1)
    raw[0, 4:8] = 0.0
    gaussians = activate_gaussians(torch.zeros(1, 3), split_confidence(raw)[0], torch.tensor(1.0), ARCHITECTURE)
    torch.testing.assert_close(gaussians.quats[0], torch.tensor([1.0, 0.0, 0.0, 0.0]))


def test_sh_degree_weights_follow_anysplat():
    weights = sh_degree_weights(4)
    assert weights.shape == (25,)
    torch.testing.assert_close(weights[[0, 1, 4, 9, 16]], torch.tensor([1.0, 0.025, 0.00625, 0.0015625, 0.000390625]))


def test_scale_is_proportional_to_scene_scale():
    params = split_confidence(_raw())[0]
    a = activate_gaussians(torch.zeros(4, 3), params, torch.tensor(1.0), ARCHITECTURE)
    b = activate_gaussians(torch.zeros(4, 3), params, torch.tensor(50.0), ARCHITECTURE)
    torch.testing.assert_close(b.scales, a.scales * 50)
    torch.testing.assert_close(F.normalize(a.quats, dim=1), a.quats)


def test_shrinking_raw_scales_divides_the_softplus_exactly():
    from lumos3d_cli.model.gaussian_adapter import SCALE, shrink_raw_scales

    raw = torch.linspace(-40, 40, 81, dtype=torch.float64)[:, None].expand(81, 14).contiguous()
    for factor in (1.0, 1.79, 2.0, 1e3):
        shrunk = shrink_raw_scales(raw, factor)
        assert torch.isfinite(shrunk).all()
        torch.testing.assert_close(F.softplus(shrunk[:, SCALE]), F.softplus(raw[:, SCALE]) / factor, rtol=1e-9, atol=1e-300)
        assert torch.equal(shrunk[:, :1], raw[:, :1]) and torch.equal(shrunk[:, 4:], raw[:, 4:])  # only the scales
    with pytest.raises(ValueError):
        shrink_raw_scales(raw, 0.5)
