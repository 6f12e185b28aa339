import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.model.appearance.conversion import with_appearance
from lumos3d_cli.model.lumos3d import build_model


def test_regression_model_initialises_an_operator_model_with_identical_geometry():
    regression = build_model("tiny", seed=0).eval()
    operator = with_appearance(regression, "operator")
    assert operator.architecture.appearance == "operator" and operator.architecture.name == "tiny-operator"
    assert with_appearance(operator, "operator") is operator
    images = torch.rand(1, 2, 3, 28, 42, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        a, b = regression(images), operator(images)
    torch.testing.assert_close(a.depth, b.depth)
    torch.testing.assert_close(a.extrinsics, b.extrinsics)
    back = with_appearance(operator, "regression")
    assert back.illumination_head is None and back.architecture.name == "tiny-regression"
    with pytest.raises(InputError, match="unknown appearance"):
        with_appearance(regression, "paint")


def test_the_local_correction_can_be_left_out_when_switching():
    regression = build_model("tiny", seed=0).eval()
    operator = with_appearance(regression, "operator", local_correction_channels=0)
    assert operator.architecture.local_correction_channels == 0 and operator.architecture.name == "tiny-operator-local0"
    images = torch.rand(1, 2, 3, 28, 42, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        assert operator.predict_appearance(images).local_log2_gain is None
    with pytest.raises(InputError, match="local_correction_channels=2"):
        with_appearance(regression, "operator", local_correction_channels=2)
    with pytest.raises(InputError, match="already has its illumination head"):
        with_appearance(with_appearance(regression, "operator"), "operator", local_correction_channels=0)
