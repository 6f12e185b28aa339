import math

import pytest
import torch

from lumos3d_cli.errors import NonFiniteError
from lumos3d_cli.io.gaussians import Gaussians, rgb_to_sh_dc, sh_dc_to_rgb, sh_degree_from_count

from factories import random_gaussians


def test_shapes_are_validated():
    good = random_gaussians(4, 1)
    with pytest.raises(ValueError, match=r"Gaussians.quats has shape \(4, 3\), expected \(4, 4\)"):
        Gaussians(good.means, good.quats[:, :3], good.scales, good.opacities, good.sh)
    with pytest.raises(ValueError, match="5 SH coefficients per channel"):
        Gaussians(good.means, good.quats, good.scales, good.opacities, torch.zeros(4, 5, 3))


def test_sh_degree_and_dc_colour():
    assert [sh_degree_from_count((d + 1) ** 2) for d in range(5)] == [0, 1, 2, 3, 4]
    rgb = torch.tensor([0.0, 0.5, 1.0])
    torch.testing.assert_close(sh_dc_to_rgb(rgb_to_sh_dc(rgb)), rgb)
    # the INRIA 3DGS convention (docs/formats.md): f_dc = 1 is 0.5 + Y_0^0 = 0.5 + 1 / (2 sqrt(pi))
    assert sh_dc_to_rgb(torch.tensor(1.0)).item() == pytest.approx(0.5 + 0.5 / math.sqrt(math.pi))


def test_select_concatenate_and_finiteness():
    g = random_gaussians(10, 2)
    both = Gaussians.concatenate([g.select(torch.arange(3)), g.select(g.opacities > 2)])
    assert len(both) == 3 and both.sh_degree == 2
    g.scales[4, 1] = float("inf")
    with pytest.raises(NonFiniteError, match=r"scene\.scales: 1 of 30"):
        g.require_finite("scene")


def test_with_sh_degree_drops_the_bands_above_it_and_keeps_the_rest():
    gaussians = random_gaussians(6, 3)
    lower = gaussians.with_sh_degree(1)
    assert lower.sh_degree == 1 and lower.sh.is_contiguous()
    assert torch.equal(lower.sh, gaussians.sh[:, :4]) and torch.equal(lower.means, gaussians.means)
    assert gaussians.with_sh_degree(3) is gaussians and gaussians.with_sh_degree(4) is gaussians
