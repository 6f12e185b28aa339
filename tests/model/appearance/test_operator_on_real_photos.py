"""The operator family can express a real exposure change: fitted to a held-out SICE bracket
pair by gradient descent, it restores far better than the blind gamma curve."""

import pytest
import torch
import torch.nn.functional as F

from lumos3d_cli.data.brackets import bracket_pairs, read_srgb
from lumos3d_cli.eval.metrics import auto_gamma, psnr
from lumos3d_cli.model.appearance.curve import CURVE_KNOTS
from lumos3d_cli.model.appearance.operator import AppearanceOperator


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["low-light", "over-exposure"])
def test_fitted_operator_beats_auto_gamma_on_a_held_out_bracket(brackets, mode):
    pair = bracket_pairs(brackets, mode, "validation")[0]
    photo, target = read_srgb(pair.input_path)[None, None], read_srgb(pair.target_path)[None, None]
    small = [F.interpolate(x[0], size=(96, 96), mode="area")[None] for x in (photo, target)]
    raw = [torch.zeros(1, 3, CURVE_KNOTS - 1, requires_grad=True), torch.zeros(1, 3, 3, requires_grad=True)]
    optimiser = torch.optim.Adam(raw, lr=0.05)
    for _ in range(150):
        optimiser.zero_grad()
        F.mse_loss(AppearanceOperator.from_raw(*raw).apply(small[0]), small[1]).backward()
        optimiser.step()
    with torch.no_grad():
        restored = AppearanceOperator.from_raw(*raw).apply(photo)
    assert bool(torch.isfinite(restored).all())
    assert float(psnr(restored, target)) > float(psnr(auto_gamma(photo), target)) + 1.0
