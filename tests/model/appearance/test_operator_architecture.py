"""The network with appearance "operator": the illumination head's operator colours the pixel
Gaussians; colour-regression architectures (and their checkpoints) are unchanged."""

import dataclasses

import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.gaussians import sh_dc_to_rgb
from lumos3d_cli.model.architectures import ARCHITECTURES, Architecture
from lumos3d_cli.model.lumos3d import build_model
from lumos3d_cli.typed_config import from_dict, to_dict


@pytest.fixture(scope="module")
def model():
    return build_model("tiny-operator", seed=0).eval()


def _images(views=2, seed=0):
    return torch.rand(1, views, 3, 28, 42, generator=torch.Generator().manual_seed(seed))


def test_untrained_operator_colours_each_pixel_gaussian_with_its_pixel(model):
    images = _images()
    with torch.no_grad():
        output = model(images)
    assert output.appearance is not None and output.appearance.curve_slopes.shape == (1, 3, 16)
    colours = sh_dc_to_rgb(output.pixel_gaussians[0].sh[:, 0])  # pixel rows in (view, row, column) order
    torch.testing.assert_close(colours, images[0].permute(0, 2, 3, 1).reshape(-1, 3), atol=2e-6, rtol=0)


def test_trained_looking_operator_changes_the_colours_and_stays_finite_at_extremes(model):
    head = model.illumination_head
    torch.nn.init.normal_(head.scene_out.weight, std=0.3)
    try:
        black_and_white = torch.stack((torch.zeros(3, 28, 42), torch.ones(3, 28, 42)))[None]
        with torch.no_grad():
            output = model(black_and_white)
            brightened = model(_images() * 0.2)
        output.appearance.require_finite()
        assert not torch.allclose(brightened.appearance.curve_slopes, torch.ones(1, 3, 16))
    finally:
        torch.nn.init.zeros_(head.scene_out.weight)


def test_predict_appearance_one_view_and_bf16(model):
    with torch.no_grad():
        operator = model.predict_appearance(_images(1))
        with torch.autocast("cpu", dtype=torch.bfloat16):
            bf16 = model.predict_appearance(_images(1))
    assert operator.local_log2_gain.shape == (1, 1, 1, 8, 8)
    assert bf16.curve_slopes.dtype == torch.float32
    bf16.require_finite()


def test_gradients_of_a_colour_loss_reach_the_illumination_head():
    model = build_model("tiny-operator", seed=1)
    output = model(_images())
    sum(g.sh[:, 0].sum() for g in output.gaussians).backward()
    assert model.illumination_head.scene_out.weight.grad is not None
    assert float(model.illumination_head.scene_out.weight.grad.abs().sum()) > 0


def test_regression_architectures_are_unchanged():
    model = build_model("tiny", seed=0)
    assert model.illumination_head is None
    assert not any(key.startswith("illumination_head.") for key in model.state_dict())
    with pytest.raises(InputError, match="regresses colours"):
        model.predict_appearance(_images(1))
    # A checkpoint's architecture written before the field existed reads as colour regression.
    values = to_dict(ARCHITECTURES["tiny"])
    for name in ("appearance", "illumination_hidden", "illumination_histogram_bins", "local_correction_channels"):
        values.pop(name)
    assert from_dict(Architecture, values).appearance == "regression"


def test_unknown_appearance_is_refused():
    with pytest.raises(ValueError, match="appearance"):
        dataclasses.replace(ARCHITECTURES["tiny"], appearance="paint")
