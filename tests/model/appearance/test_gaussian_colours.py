import dataclasses

import pytest
import torch

from lumos3d_cli.io.gaussians import sh_dc_to_rgb
from lumos3d_cli.model.appearance.gaussian_colours import with_operator_colours
from lumos3d_cli.model.architectures import ARCHITECTURES
from lumos3d_cli.model.gaussian_adapter import SH_START, activate_gaussians


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_activated_gaussians_carry_the_restored_colours(degree):
    architecture = dataclasses.replace(ARCHITECTURES["tiny"], sh_degree=degree)
    channels = SH_START + 3 * (degree + 1) ** 2
    params = torch.randn(1, 2, 3, 4, channels)
    colours = torch.rand(1, 2, 3, 3, 4, requires_grad=True)
    replaced = with_operator_colours(params, colours, degree)
    torch.testing.assert_close(replaced[..., :SH_START], params[..., :SH_START])
    gaussians = activate_gaussians(torch.zeros(24, 3), replaced.reshape(24, -1), torch.tensor(1.0), architecture)
    expected = colours.permute(0, 1, 3, 4, 2).reshape(24, 3)
    torch.testing.assert_close(sh_dc_to_rgb(gaussians.sh[:, 0]), expected)
    assert float(gaussians.sh[:, 1:].detach().abs().sum()) == 0
    replaced.sum().backward()
    assert colours.grad is not None and float(colours.grad.abs().sum()) > 0


def test_wrong_channel_count_is_refused():
    with pytest.raises(ValueError, match="expected"):
        with_operator_colours(torch.zeros(1, 1, 2, 2, 10), torch.zeros(1, 1, 3, 2, 2), 1)
