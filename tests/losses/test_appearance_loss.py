import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from lumos3d_cli.losses.appearance import appearance_loss
from lumos3d_cli.losses.ssim import ssim_map_mean


def _pair(seed=0, shape=(2, 3, 24, 30)):
    generator = torch.Generator().manual_seed(seed)
    a = torch.rand(shape, generator=generator, dtype=torch.float64)
    b = (a + 0.2 * torch.randn(shape, generator=generator, dtype=torch.float64)).clamp(0, 1)
    return a, b


def test_ssim_matches_scikit_image():
    a, b = _pair()
    values = ssim_map_mean(a, b)
    for i in range(2):
        expected = structural_similarity(
            b[i].permute(1, 2, 0).numpy(), a[i].permute(1, 2, 0).numpy(), channel_axis=2, data_range=1,
            gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
        )
        assert float(values[i]) == pytest.approx(expected, abs=1e-10)
    assert float(ssim_map_mean(a.float(), b.float())[0]) == pytest.approx(float(values[0]), abs=1e-5)


def test_ssim_gradient_is_correct_in_float64():
    a, b = _pair(1, (1, 3, 13, 14))
    a.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: ssim_map_mean(x, b), (a,))


def test_loss_is_zero_for_equal_images_and_grows_with_error():
    a, b = _pair(2)
    assert float(appearance_loss(a, a)) == pytest.approx(0, abs=1e-6)
    assert float(appearance_loss(b, a)) > float(appearance_loss((a + b) / 2, a)) > 0
    l1 = float(torch.mean(torch.abs(b - a)))
    assert float(appearance_loss(b, a, ssim_weight=0)) == pytest.approx(l1, rel=1e-6)


@pytest.mark.parametrize("fill", [0.0, 1.0])
def test_black_and_saturated_images_give_finite_losses_and_gradients(fill):
    restored = torch.full((1, 3, 16, 16), fill, requires_grad=True)
    loss = appearance_loss(restored, torch.full((1, 3, 16, 16), 1 - fill))
    loss.backward()
    assert bool(torch.isfinite(loss)) and bool(torch.isfinite(restored.grad).all())


def test_bf16_inputs_are_computed_in_float32():
    a, b = _pair(3)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        loss = appearance_loss(b.bfloat16(), a.bfloat16())
    assert loss.dtype == torch.float32
    assert float(loss) == pytest.approx(float(appearance_loss(b.bfloat16().float(), a.bfloat16().float())), rel=1e-5)
    assert np.isfinite(float(loss))
