import pytest
import torch

from lumos3d_cli.model.appearance.curve import CURVE_KNOTS
from lumos3d_cli.model.appearance.illumination_head import IlluminationHead

TOKEN_DIM, START, PATCH = 32, 5, 14


def _inputs(batch=1, views=2, rows=2, columns=3, seed=0):
    generator = torch.Generator().manual_seed(seed)
    tokens = torch.randn(batch, views, START + rows * columns, TOKEN_DIM, generator=generator)
    images = torch.rand(batch, views, 3, rows * PATCH, columns * PATCH, generator=generator)
    return tokens, images


def _trained_looking_head(**options) -> IlluminationHead:
    """A head whose zero-initialised output layers were given random weights."""
    torch.manual_seed(0)
    head = IlluminationHead(TOKEN_DIM, START, PATCH, hidden=16, **options)
    for layer in [head.scene_out] + ([head.local_mlp[-1]] if head.local_channels else []):
        torch.nn.init.normal_(layer.weight, std=0.5)
        torch.nn.init.normal_(layer.bias, std=0.5)
    return head


def test_untrained_head_is_the_identity():
    head = IlluminationHead(TOKEN_DIM, START, PATCH, hidden=16)
    tokens, images = _inputs(2, 3)
    operator = head(tokens, images)
    assert operator.curve_slopes.shape == (2, 3, CURVE_KNOTS - 1)
    assert operator.matrix.shape == (2, 3, 3)
    assert operator.local_log2_gain.shape == (2, 3, 1, 8, 8)
    torch.testing.assert_close(operator.apply(images), images, atol=2e-6, rtol=0)


@pytest.mark.parametrize("views", [1, 64])
def test_one_and_many_views(views):
    head = _trained_looking_head(local_channels=3)
    tokens, images = _inputs(1, views, rows=1, columns=1)  # 14 x 14 images: fewer patches than grid cells
    operator = head(tokens, images)
    assert operator.local_log2_gain.shape == (1, views, 3, 8, 8)
    operator.require_finite()
    assert bool(torch.isfinite(operator.apply(images)).all())


def test_scene_operator_ignores_view_order():
    head = _trained_looking_head()
    tokens, images = _inputs(1, 4)
    order = torch.tensor([2, 0, 3, 1])
    a, b = head(tokens, images), head(tokens[:, order], images[:, order])
    torch.testing.assert_close(a.curve_slopes, b.curve_slopes)
    torch.testing.assert_close(a.matrix, b.matrix)
    torch.testing.assert_close(a.local_log2_gain[:, order], b.local_log2_gain)


def test_histograms_and_local_correction_can_be_left_out():
    head = _trained_looking_head(histogram_bins=0, local_channels=0)
    tokens, images = _inputs()
    operator = head(tokens, images)
    assert operator.local_log2_gain is None
    # Without histograms the scene operator depends on the tokens alone.
    torch.testing.assert_close(head(tokens, images.flip(-1)).curve_slopes, operator.curve_slopes)


def test_histograms_inform_the_operator():
    head = _trained_looking_head()
    tokens, images = _inputs()
    assert not torch.allclose(head(tokens, images).curve_slopes, head(tokens, images * 0.1).curve_slopes)


def test_black_and_saturated_frames_with_extreme_tokens_stay_finite():
    head = _trained_looking_head()
    tokens, _ = _inputs(1, 2)
    images = torch.stack((torch.zeros(3, 28, 42), torch.ones(3, 28, 42)))[None]
    operator = head(tokens * 1e4, images)
    operator.require_finite()
    assert bool(torch.isfinite(operator.apply(images)).all())


def test_bf16_autocast_gives_float32_parameters_close_to_float32():
    head = _trained_looking_head()
    tokens, images = _inputs(1, 3)
    expected = head(tokens, images)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        operator = head(tokens.bfloat16(), images.bfloat16())
    assert operator.curve_slopes.dtype == torch.float32 and operator.local_log2_gain.dtype == torch.float32
    torch.testing.assert_close(operator.curve_slopes, expected.curve_slopes, rtol=0.05, atol=0.01)


def test_gradients_reach_the_head_and_the_tokens():
    head = _trained_looking_head()
    tokens, images = _inputs()
    tokens.requires_grad_(True)
    head(tokens, images).apply(images * 0.3).mean().backward()
    assert float(tokens.grad.abs().sum()) > 0
    for name, parameter in head.named_parameters():
        assert parameter.grad is not None and bool(torch.isfinite(parameter.grad).all()), name
