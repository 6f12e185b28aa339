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
from dataclasses import dataclass, field
from typing import Literal

import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.io.colour import linear_to_srgb, srgb_to_linear

MODES: tuple[str, ...] = ("low-light", "over-exposure")


@dataclass(frozen=True)
class SensorNoise:
    """Ranges of the shot/read noise model (variances per unit linear signal)."""

    shot_range: tuple[float, float] = (1e-4, 1.2e-2)
    read_slope: float = 2.18
    read_intercept: float = 1.2
    read_jitter: float = 0.26


SENSOR_NOISE = SensorNoise()


@dataclass(frozen=True)
class ModeRanges:
    """Exposure and gamma ranges of one mode (None: the mode's documented range)."""

    exposure: tuple[float, float] | None = None
    gamma: tuple[float, float] | None = None


DOCUMENTED_RANGES = {
    "low-light": ModeRanges(exposure=(0.05, 0.1), gamma=(1.3, 1.4)),
    "over-exposure": ModeRanges(exposure=(5.0, 15.0), gamma=(1.5, 2.0)),
}


@dataclass(frozen=True)
class Degradation:
    """What to synthesise: the settings of `lumos3d degrade` and of the training config's
    `degrade` section (built from YAML by `typed_config.from_dict`).

    `mixed` draws low-light or over-exposure with equal probability per call of `degrade`, with
    the ranges of `low_light` and `over_exposure`; the single modes use `exposure` and `gamma`.
    `consistent_views` shares one draw among the views of a scene (one camera setting);
    `white_balance` is the per-channel linear gain range of `white_balance_shift`.
    """

    mode: Literal["low-light", "over-exposure", "mixed"] = "low-light"
    exposure: tuple[float, float] | None = None  # None: the mode's documented range
    gamma: tuple[float, float] | None = None
    low_light: ModeRanges = field(default_factory=ModeRanges)
    over_exposure: ModeRanges = field(default_factory=ModeRanges)
    noise: bool = False
    consistent_views: bool = True
    white_balance: tuple[float, float] = (1.0, 1.0)

    def __post_init__(self) -> None:
        if self.mode not in (*MODES, "mixed"):
            raise ValueError(f"unknown degradation mode {self.mode!r}; use one of {', '.join(MODES)} or mixed")
        if self.mode == "mixed" and (self.exposure is not None or self.gamma is not None):
            raise ValueError("degrade.mode=mixed takes its ranges from degrade.low_light and degrade.over_exposure; "
                             "remove degrade.exposure and degrade.gamma")

    def ranges(self, mode: str) -> ModeRanges:
        """The exposure and gamma ranges drawn for the single mode `mode`, documented ranges
        filling what is not configured."""
        if mode not in MODES:
            raise ValueError(f"unknown degradation mode {mode!r}; use one of {', '.join(MODES)}")
        if self.mode == "mixed":
            configured = self.low_light if mode == "low-light" else self.over_exposure
        else:
            configured = ModeRanges(self.exposure, self.gamma)
        documented = DOCUMENTED_RANGES[mode]
        return ModeRanges(configured.exposure or documented.exposure, configured.gamma or documented.gamma)

    def pick_mode(self, generator: torch.Generator) -> str:
        """The single mode of one draw: `mode`, or for `mixed` a fair coin from `generator`."""
        if self.mode != "mixed":
            return self.mode
        return "low-light" if torch.rand((), generator=generator).item() < 0.5 else "over-exposure"


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
    degradation: Degradation, shape: tuple[int, ...], generator: torch.Generator, mode: str | None = None
) -> DegradationParameters:
    """Draw parameters of `shape` (one per image, or fewer dims to share them across images) for
    the single mode `mode` (default: the degradation's own, which must then not be mixed)."""
    ranges = degradation.ranges(mode or degradation.mode)
    exposure = _uniform(shape, *ranges.exposure, generator)
    gamma = _uniform(shape, *ranges.gamma, generator)
    if not degradation.noise:
        return DegradationParameters(exposure, gamma)
    noise = SENSOR_NOISE
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
    images: torch.Tensor, degradation: Degradation, generator: torch.Generator
) -> tuple[torch.Tensor, DegradationParameters]:
    """Degrade sRGB images [..., 3, H, W] in [0, 1]; returns (images, parameters [...]).

    One mode is picked per call (`Degradation.pick_mode`). Parameters are drawn per image, or per
    scene with `degradation.consistent_views` (then images are [B, V, 3, H, W] and the V views of
    a scene share them, as one camera setting would). All randomness comes from `generator`, so a
    seed fixes the result.
    """
    batch_shape = tuple(images.shape[:-3])
    if degradation.consistent_views and images.dim() != 5:
        raise ValueError(f"consistent_views needs [B, V, 3, H, W] images, got {tuple(images.shape)}")
    mode = degradation.pick_mode(generator)
    draw_shape = batch_shape[:1] + (1,) if degradation.consistent_views else batch_shape
    parameters = sample_parameters(degradation, draw_shape, generator, mode)
    return apply_degradation(images, mode, parameters, generator), parameters


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
