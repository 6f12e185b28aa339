"""Synthetic low-light and over-exposure, batched in torch, deterministic with a generator.

All work happens in linear RGB: sRGB in -> decode -> expose -> (sensor noise) -> tone -> encode.

low-light (the paper):  y = (k * x) ** g,            k ~ U(0.05, 0.1),  g ~ U(1.3, 1.4)
over-exposure (ours):   y = (1 - exp(-k * x)) ** (1/g), k ~ U(5, 15),    g ~ U(1.5, 2.0)

The over-exposure curve pushes the scene up an exponential saturation shoulder, so highlights
roll off into white rather than clipping at one level, then lifts the mid-tones; its parameter
ranges were fitted to LOM's `buu` `high/` -> `over_exp/` pairs (docs/formats.md has the numbers).

Sensor noise (optional) is the heteroscedastic Gaussian approximation of Poisson-Gaussian noise,
added to the exposed linear signal: y += sqrt(shot * y + read) * n, n ~ N(0, 1), with
log(shot) ~ U(log 1e-4, log 1.2e-2) and log(read) = 2.18 log(shot) + 1.2 + N(0, 0.26^2)
(the camera noise model of Brooks et al., "Unprocessing Images for Learned Raw Denoising", 2019).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.io.colour import linear_to_srgb, srgb_to_linear

Mode = Literal["low-light", "over-exposure"]
MODES: tuple[str, ...] = ("low-light", "over-exposure")


@dataclass(frozen=True)
class SensorNoise:
    """Ranges of the shot/read noise model (variances per unit linear signal)."""

    shot_range: tuple[float, float] = (1e-4, 1.2e-2)
    read_slope: float = 2.18
    read_intercept: float = 1.2
    read_jitter: float = 0.26


@dataclass(frozen=True)
class Degradation:
    """What to synthesise: the mode, its parameter ranges, optional sensor noise."""

    mode: Mode = "low-light"
    exposure_range: tuple[float, float] = (0.05, 0.1)
    gamma_range: tuple[float, float] = (1.3, 1.4)
    noise: SensorNoise | None = None

    @staticmethod
    def for_mode(mode: str, noise: bool = False) -> Degradation:
        """The documented defaults of `mode`."""
        sensor = SensorNoise() if noise else None
        if mode == "low-light":
            return Degradation("low-light", (0.05, 0.1), (1.3, 1.4), sensor)
        if mode == "over-exposure":
            return Degradation("over-exposure", (5.0, 15.0), (1.5, 2.0), sensor)
        raise ValueError(f"unknown degradation mode {mode!r}; use one of {', '.join(MODES)}")


@dataclass
class DegradationParameters:
    """Drawn parameters, broadcastable to the images' batch shape [...] (float64)."""

    exposure: torch.Tensor
    gamma: torch.Tensor
    shot: torch.Tensor | None = None
    read: torch.Tensor | None = None

    def as_dict(self, index: tuple[int, ...] = ()) -> dict[str, float]:
        """Plain floats of one image (for logs and JSON)."""
        values = {"exposure": self.exposure, "gamma": self.gamma, "shot_noise": self.shot, "read_noise": self.read}
        return {name: float(v[index]) for name, v in values.items() if v is not None}


def _uniform(shape, low: float, high: float, generator: torch.Generator) -> torch.Tensor:
    return low + (high - low) * torch.rand(shape, generator=generator, device=generator.device, dtype=torch.float64)


def sample_parameters(
    degradation: Degradation, shape: tuple[int, ...], generator: torch.Generator
) -> DegradationParameters:
    """Draw parameters of `shape` (one per image, or fewer dims to share them across images)."""
    exposure = _uniform(shape, *degradation.exposure_range, generator)
    gamma = _uniform(shape, *degradation.gamma_range, generator)
    if degradation.noise is None:
        return DegradationParameters(exposure, gamma)
    noise = degradation.noise
    log_shot = _uniform(shape, *(math.log(v) for v in noise.shot_range), generator)
    jitter = noise.read_jitter * torch.randn(shape, generator=generator, device=generator.device, dtype=torch.float64)
    log_read = noise.read_slope * log_shot + noise.read_intercept + jitter
    return DegradationParameters(exposure, gamma, log_shot.exp(), log_read.exp())


def apply_degradation(
    images: torch.Tensor, mode: str, parameters: DegradationParameters, generator: torch.Generator
) -> torch.Tensor:
    """Degrade sRGB images [..., 3, H, W] in [0, 1] with given parameters (broadcast over the
    batch dims); the generator supplies the noise samples."""
    if images.dim() < 3 or images.shape[-3] != 3:
        raise ValueError(f"images must be [..., 3, H, W], got {tuple(images.shape)}")
    require_finite("images to degrade", images)

    def per_image(values: torch.Tensor) -> torch.Tensor:
        values = values.to(device=images.device, dtype=images.dtype)
        return values.expand(images.shape[:-3])[..., None, None, None]

    exposed = srgb_to_linear(images.clamp(0.0, 1.0)) * per_image(parameters.exposure)
    if parameters.shot is not None and parameters.read is not None:
        variance = per_image(parameters.shot) * exposed + per_image(parameters.read)
        normal = torch.randn(images.shape, generator=generator, device=generator.device, dtype=images.dtype)
        exposed = (exposed + variance.sqrt() * normal.to(images.device)).clamp_min(0.0)
    if mode == "low-light":
        toned = exposed ** per_image(parameters.gamma)
    elif mode == "over-exposure":
        toned = (-torch.expm1(-exposed)) ** (1.0 / per_image(parameters.gamma))
    else:
        raise ValueError(f"unknown degradation mode {mode!r}; use one of {', '.join(MODES)}")
    return linear_to_srgb(toned.clamp(0.0, 1.0))


def degrade(
    images: torch.Tensor,
    degradation: Degradation,
    generator: torch.Generator,
    consistent_views: bool = False,
) -> tuple[torch.Tensor, DegradationParameters]:
    """Degrade sRGB images [..., 3, H, W] in [0, 1]; returns (images, parameters [...]).

    Parameters are drawn per image, or per scene when `consistent_views` is set (then images are
    [B, V, 3, H, W] and the V views of a scene share them, as one camera setting would). All
    randomness comes from `generator`, so a seed fixes the result.
    """
    batch_shape = tuple(images.shape[:-3])
    if consistent_views and images.dim() != 5:
        raise ValueError(f"consistent_views needs [B, V, 3, H, W] images, got {tuple(images.shape)}")
    draw_shape = batch_shape[:1] + (1,) if consistent_views else batch_shape
    parameters = sample_parameters(degradation, draw_shape, generator)
    return apply_degradation(images, degradation.mode, parameters, generator), parameters


def white_balance_shift(images: torch.Tensor, gain_range: tuple[float, float], generator: torch.Generator) -> torch.Tensor:
    """Augmentation: multiply the linear red and blue channels of each scene [B, V, 3, H, W] by
    gains drawn from `gain_range` (green fixed), like a different colour temperature; re-encode.
    Applied to the normal-light images before degradation, so targets and inputs agree."""
    low, high = gain_range
    if low == high == 1.0:
        return images
    gains = _uniform((images.shape[0], 3), low, high, generator)
    gains[:, 1] = 1.0
    linear = srgb_to_linear(images.clamp(0.0, 1.0)) * gains.to(images)[:, None, :, None, None]
    return linear_to_srgb(linear.clamp(0.0, 1.0))
