import math

import cv2
import numpy as np
import pytest
import torch

from lumos3d_cli.data.degradations import (
    Degradation,
    DegradationParameters,
    ModeRanges,
    apply_degradation,
    degrade,
    sample_parameters,
)
from lumos3d_cli.errors import NonFiniteError
from lumos3d_cli.io.colour import linear_to_srgb, srgb_to_linear


def _images(*shape, seed=0):
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed))


def _load_folder(folder, suffix, step=2):
    paths = sorted(folder.glob(f"*.{suffix}"), key=lambda p: int(p.stem))
    return torch.stack([torch.from_numpy(cv2.imread(str(p))[::step, ::step, ::-1] / 255.0) for p in paths]).permute(0, 3, 1, 2)


def test_low_light_is_the_paper_formula():
    images = _images(2, 3, 8, 8)
    parameters = DegradationParameters(torch.tensor([0.05, 0.1], dtype=torch.float64), torch.tensor([1.3, 1.4], dtype=torch.float64))
    out = apply_degradation(images, "low-light", parameters, torch.Generator())
    for i, (k, g) in enumerate([(0.05, 1.3), (0.1, 1.4)]):
        expected = linear_to_srgb((srgb_to_linear(images[i].double()) * k) ** g)
        torch.testing.assert_close(out[i].double(), expected, atol=1e-6, rtol=0)


def test_over_exposure_is_the_documented_formula():
    images = _images(1, 3, 8, 8)
    parameters = DegradationParameters(torch.tensor([10.0], dtype=torch.float64), torch.tensor([1.75], dtype=torch.float64))
    out = apply_degradation(images, "over-exposure", parameters, torch.Generator())
    expected = linear_to_srgb((1 - torch.exp(-10 * srgb_to_linear(images[0].double()))) ** (1 / 1.75))
    torch.testing.assert_close(out[0].double(), expected, atol=1e-6, rtol=0)


@pytest.mark.parametrize("mode", ["low-light", "over-exposure"])
def test_deterministic_with_a_seed_and_within_ranges(mode):
    images = _images(4, 3, 3, 16, 16)
    degradation = Degradation(mode, noise=True, consistent_views=False)
    a, pa = degrade(images, degradation, torch.Generator().manual_seed(7))
    b, pb = degrade(images, degradation, torch.Generator().manual_seed(7))
    c, _ = degrade(images, degradation, torch.Generator().manual_seed(8))
    assert torch.equal(a, b) and torch.equal(pa.exposure, pb.exposure)
    assert not torch.equal(a, c)
    assert a.shape == images.shape and a.dtype == images.dtype
    low, high = degradation.ranges(mode).exposure
    assert ((pa.exposure >= low) & (pa.exposure <= high)).all()
    low, high = degradation.ranges(mode).gamma
    assert ((pa.gamma >= low) & (pa.gamma <= high)).all()
    assert pa.exposure.shape == (4, 3)


def test_views_of_a_scene_can_share_parameters():
    images = _images(2, 5, 3, 8, 8)
    out, parameters = degrade(images, Degradation("low-light", consistent_views=True), torch.Generator().manual_seed(0))
    assert parameters.exposure.shape == (2, 1)
    # Same input view content -> same output within a scene.
    same = images[:, :1].expand(-1, 5, -1, -1, -1)
    out, _ = degrade(same, Degradation("low-light", consistent_views=True), torch.Generator().manual_seed(0))
    assert torch.equal(out[0, 0], out[0, 4]) and not torch.equal(out[0, 0], out[1, 0])


def test_mixed_draws_both_modes_each_with_its_own_ranges():
    degradation = Degradation("mixed", low_light=ModeRanges(exposure=(0.02, 0.03)), over_exposure=ModeRanges(gamma=(2.5, 2.6)),
                              consistent_views=False)
    assert degradation.ranges("low-light") == ModeRanges(exposure=(0.02, 0.03), gamma=(1.3, 1.4))  # unset: documented
    assert degradation.ranges("over-exposure") == ModeRanges(exposure=(5.0, 15.0), gamma=(2.5, 2.6))
    images = _images(3, 3, 4, 4)
    drawn = {"low-light": 0, "over-exposure": 0}
    for seed in range(40):
        out, parameters = degrade(images, degradation, torch.Generator().manual_seed(seed))
        if ((parameters.exposure >= 0.02) & (parameters.exposure <= 0.03)).all():
            drawn["low-light"] += 1
            assert ((parameters.gamma >= 1.3) & (parameters.gamma <= 1.4)).all() and out.mean() < images.mean()
        else:
            drawn["over-exposure"] += 1
            assert ((parameters.exposure >= 5.0) & (parameters.exposure <= 15.0)).all()
            assert ((parameters.gamma >= 2.5) & (parameters.gamma <= 2.6)).all() and out.mean() > images.mean()
    assert min(drawn.values()) >= 10


def test_settings_are_checked():
    with pytest.raises(ValueError, match="unknown degradation mode 'dusk'"):
        Degradation("dusk")
    with pytest.raises(ValueError, match="mixed takes its ranges from degrade.low_light"):
        Degradation("mixed", exposure=(0.1, 0.2))
    with pytest.raises(ValueError, match="unknown degradation mode 'mixed'"):
        sample_parameters(Degradation("mixed"), (2,), torch.Generator())
    with pytest.raises(ValueError, match=r"degrade.exposure=\(0.2, 0.1\) must satisfy 1e-06 <= low <= high <= 1e\+06"):
        Degradation("low-light", exposure=(0.2, 0.1))
    with pytest.raises(ValueError, match=r"degrade.over_exposure.gamma=\(-1.0, 2.0\)"):
        Degradation("mixed", over_exposure=ModeRanges(gamma=(-1.0, 2.0)))
    with pytest.raises(ValueError, match="degrade.gamma"):
        Degradation("low-light", gamma=(1.0, math.inf))


@pytest.mark.parametrize("mode", ["low-light", "over-exposure"])
@pytest.mark.parametrize("fill", [0.0, 1.0])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64, torch.bfloat16])
def test_black_and_saturated_frames_stay_finite(mode, fill, dtype):
    images = torch.full((2, 3, 8, 8), fill, dtype=dtype)
    out, _ = degrade(images, Degradation(mode, noise=True, consistent_views=False), torch.Generator().manual_seed(0))
    assert torch.isfinite(out).all() and out.min() >= 0 and out.max() <= 1
    if fill == 0.0 and mode == "low-light":
        assert out.float().mean() < 0.02  # only noise on black


def test_non_finite_input_is_refused():
    images = torch.zeros(1, 3, 4, 4)
    images[0, 0, 0, 0] = float("nan")
    with pytest.raises(NonFiniteError, match="images to degrade: 1 of 48"):
        degrade(images, Degradation("low-light", consistent_views=False), torch.Generator())


def test_sensor_noise_variance_follows_the_model():
    flat = torch.full((1, 3, 256, 256), 0.5, dtype=torch.float64)
    parameters = DegradationParameters(
        torch.tensor([1.0], dtype=torch.float64), torch.tensor([1.0], dtype=torch.float64),
        torch.tensor([1e-3], dtype=torch.float64), torch.tensor([1e-5], dtype=torch.float64),
    )
    out = apply_degradation(flat, "low-light", parameters, torch.Generator().manual_seed(0))
    linear = srgb_to_linear(out)
    signal = srgb_to_linear(torch.tensor(0.5, dtype=torch.float64))
    expected_std = math.sqrt(1e-3 * signal + 1e-5)
    assert linear.mean().item() == pytest.approx(signal.item(), rel=1e-2)
    assert linear.std().item() == pytest.approx(expected_std, rel=2e-2)


def test_sampled_noise_levels_follow_the_camera_model():
    parameters = sample_parameters(Degradation("low-light", noise=True), (20000,), torch.Generator().manual_seed(0))
    log_shot, log_read = parameters.shot.log(), parameters.read.log()
    assert log_shot.min() >= math.log(1e-4) and log_shot.max() <= math.log(1.2e-2)
    residual = log_read - (2.18 * log_shot + 1.2)
    assert residual.mean().abs() < 0.01 and residual.std().item() == pytest.approx(0.26, rel=0.03)


def test_over_exposure_statistics_resemble_lom(buu):
    """The synthetic over-exposure of buu's normal-light views should look like LOM's real ones."""
    high = _load_folder(buu / "high", "JPG")
    real = _load_folder(buu / "over_exp", "jpg")
    degradation = Degradation("over-exposure", consistent_views=False)
    means = []
    for seed in range(8):
        synthetic, _ = degrade(high, degradation, torch.Generator().manual_seed(seed))
        means.append(synthetic.mean().item())
    assert real.mean().item() == pytest.approx(0.914, abs=0.01)
    assert np.mean(means) == pytest.approx(real.mean().item(), abs=0.04)
    # At the centre of the ranges the synthesis is close pixel by pixel, not only on average.
    centre = DegradationParameters(torch.tensor(10.0, dtype=torch.float64), torch.tensor(1.75, dtype=torch.float64))
    synthetic = apply_degradation(high, "over-exposure", centre, torch.Generator())
    psnr = -10 * torch.log10(((synthetic - real) ** 2).mean()).item()
    assert psnr > 27.0
    # The real set has a bright, compressed distribution: similar spread and highlight share.
    assert synthetic.std().item() == pytest.approx(real.std().item(), abs=0.03)


def test_low_light_synthesis_is_in_the_range_of_lom(buu):
    high = _load_folder(buu / "high", "JPG")
    real = _load_folder(buu / "low", "JPG")
    degradation = Degradation("low-light")
    darkest = apply_degradation(high, "low-light", DegradationParameters(torch.tensor(0.05), torch.tensor(1.4)), torch.Generator())
    brightest = apply_degradation(high, "low-light", DegradationParameters(torch.tensor(0.1), torch.tensor(1.3)), torch.Generator())
    assert darkest.mean() < brightest.mean() < real.mean() * 1.2
    assert real.mean().item() == pytest.approx(0.091, abs=0.005)
    assert 0.02 < darkest.mean().item() and brightest.mean().item() > 0.06
    assert degradation.ranges("low-light") == ModeRanges(exposure=(0.05, 0.1), gamma=(1.3, 1.4))


def test_colour_cast_is_a_linear_gain_on_red_and_blue_only():
    images = _images(3, 8, 8, seed=4) * 0.5 + 0.25
    plain = DegradationParameters(torch.tensor(0.5, dtype=torch.float64), torch.tensor(1.0, dtype=torch.float64))
    cast = DegradationParameters(plain.exposure, plain.gamma, cast=torch.tensor([0.8, 1.0, 1.25], dtype=torch.float64))
    base = srgb_to_linear(apply_degradation(images.double(), "low-light", plain, torch.Generator()))
    shifted = srgb_to_linear(apply_degradation(images.double(), "low-light", cast, torch.Generator()))
    ratio = (shifted / base).mean(dim=(1, 2))
    assert torch.allclose(ratio, torch.tensor([0.8, 1.0, 1.25], dtype=torch.float64), atol=1e-6)


def test_sampled_casts_are_log_uniform_in_range_with_green_fixed():
    parameters = sample_parameters(Degradation("low-light", colour_cast=(0.8, 1.25)), (4000,), torch.Generator().manual_seed(1))
    assert torch.all(parameters.cast[:, 1] == 1)
    red_blue = parameters.cast[:, [0, 2]]
    assert red_blue.min() >= 0.8 and red_blue.max() <= 1.25
    assert abs(float(red_blue.log().mean())) < 0.01  # log-symmetric: a gain and its inverse equally likely


def test_quantisation_leaves_eight_bit_levels():
    parameters = DegradationParameters(torch.tensor(0.05, dtype=torch.float64), torch.tensor(1.3, dtype=torch.float64), quantize=True)
    out = apply_degradation(_images(3, 16, 16, seed=2), "low-light", parameters, torch.Generator())
    levels = out * 255
    assert torch.allclose(levels, levels.round(), atol=1e-4)
    assert levels.max() < 64  # a dark 8-bit photo holds few levels: what banding is made of


def test_jpeg_matches_opencv_round_trip():
    image = _images(3, 32, 48, seed=5)
    parameters = DegradationParameters(torch.tensor(1.0, dtype=torch.float64), torch.tensor(1.0, dtype=torch.float64),
                                       jpeg_quality=torch.tensor(80.0, dtype=torch.float64))
    out = apply_degradation(image.double(), "low-light", parameters, torch.Generator())
    plain = apply_degradation(image.double(), "low-light", DegradationParameters(parameters.exposure, parameters.gamma), torch.Generator())
    pixels = (plain.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    _, encoded = cv2.imencode(".jpg", pixels[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 80])
    expected = cv2.imdecode(encoded, cv2.IMREAD_COLOR)[..., ::-1] / 255.0
    assert np.array_equal(out.permute(1, 2, 0).numpy(), expected)


def test_camera_pipeline_draws_are_reproducible_and_recorded():
    settings = Degradation("low-light", noise=True, colour_cast=(0.8, 1.25), quantize=True, jpeg_quality=(75, 98))
    images = _images(2, 3, 3, 16, 16, seed=6)
    first, parameters = degrade(images, settings, torch.Generator().manual_seed(9))
    second, _ = degrade(images, settings, torch.Generator().manual_seed(9))
    assert torch.equal(first, second)
    record = parameters.as_dict((0, 0))
    assert 75 <= record["jpeg_quality"] <= 98 and record["bits"] == 8 and len(record["colour_cast"]) == 3


@pytest.mark.parametrize("field, value", [("colour_cast", (0.0, 1.0)), ("colour_cast", (1.2, 1.1)), ("jpeg_quality", (0, 90)),
                                          ("jpeg_quality", (95, 90))])
def test_camera_pipeline_settings_are_checked(field, value):
    with pytest.raises(ValueError, match=field):
        Degradation("low-light", **{field: value})
