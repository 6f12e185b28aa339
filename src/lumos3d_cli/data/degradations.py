"""Synthetic low-light and over-exposure, batched in torch, deterministic with a generator.

All work happens in linear RGB: sRGB in -> decode -> expose -> (sensor noise) -> tone -> encode.

low-light (the paper):  y = (k * x) ** g,            k ~ U(0.05, 0.1),  g ~ U(1.3, 1.4)
over-exposure (ours):   y = (1 - exp(-k * x)) ** (1/g), k ~ U(5, 15),    g ~ U(1.5, 2.0)

The over-exposure curve pushes the scene up an exponential saturation shoulder, so highlights
roll off into white rather than clipping at one level, then lifts the mid-tones; its parameter
ranges were fitted to LOM's `buu` `high/` -> `over_exp/` pairs (docs/formats.md has the numbers).

The full camera pipeline adds, when configured: a colour cast (a per-channel gain on red and blue
in linear light, on the degraded photo only: a wrong white balance the restoration must undo),
8-bit quantisation (the shadows of a dark 8-bit photo hold a few levels, which an amplifying
restoration turns into banding) and JPEG compression at a drawn quality (OpenCV's encoder).

Sensor noise (optional) is the heteroscedastic Gaussian approximation of Poisson-Gaussian noise,
added to the exposed linear signal: y += sqrt(shot * y + read) * n, n ~ N(0, 1), with
log(shot) ~ U(log 1e-4, log 1.2e-2) and log(read) = 2.18 log(shot) + 1.2 + N(0, 0.26^2)
(the camera noise model of Brooks et al., "Unprocessing Images for Learned Raw Denoising", 2019).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.data.modes import MODES
from lumos3d_cli.io.colour import linear_to_srgb, srgb_to_linear


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


# The widest exposure and gamma ranges: 20 stops either way, and curves from nearly flat to nearly
# a step; beyond them float32 overflows (an exposure of 1e308 is Inf, and Inf times a black pixel NaN).
RANGE_LIMITS = {"exposure": (1e-6, 1e6), "gamma": (1e-2, 1e2)}
# The largest red/blue gain `degrade --colour-cast` draws from: far beyond any white balance (a
# tungsten photo on a daylight setting is about 2), short of what overflows float32 sRGB.
MAX_COLOUR_CAST = 100.0


def is_valid_range(bounds: tuple[float, float], kind: str) -> bool:
    """Whether an exposure or gamma range (low, high), `kind` "exposure" or "gamma", has
    low <= high within RANGE_LIMITS[kind]."""
    lowest, highest = RANGE_LIMITS[kind]
    return lowest <= bounds[0] <= bounds[1] <= highest


def range_rule(kind: str) -> str:
    """What `is_valid_range` asks of a `kind` range, in words."""
    lowest, highest = RANGE_LIMITS[kind]
    return f"{lowest:g} <= low <= high <= {highest:g}"


@dataclass(frozen=True)
class Degradation:
    """What to synthesise: the settings of `lumos3d degrade` and of the training config's
    `degrade` section (built from YAML by `typed_config.from_dict`).

    `mixed` draws low-light or over-exposure with equal probability per call of `degrade`, with
    the ranges of `low_light` and `over_exposure`; the single modes use `exposure` and `gamma`.
    `consistent_views` shares one draw among the views of a scene (one camera setting);
    `white_balance` is the per-channel linear gain range of `white_balance_shift` (targets and
    inputs alike); `colour_cast` the range of the red and blue linear gains applied to the degraded
    image only; `quantize` rounds the result to 8 bits; `jpeg_quality` (low, high) compresses it
    as JPEG at a quality drawn from that range (None: no JPEG; JPEG implies 8 bits).
    """

    mode: Literal["low-light", "over-exposure", "mixed"] = "low-light"
    exposure: tuple[float, float] | None = None  # None: the mode's documented range
    gamma: tuple[float, float] | None = None
    low_light: ModeRanges = field(default_factory=ModeRanges)
    over_exposure: ModeRanges = field(default_factory=ModeRanges)
    noise: bool = False
    consistent_views: bool = True
    white_balance: tuple[float, float] = (1.0, 1.0)
    colour_cast: tuple[float, float] = (1.0, 1.0)
    quantize: bool = False
    jpeg_quality: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if self.mode not in (*MODES, "mixed"):
            raise ValueError(f"unknown degradation mode {self.mode!r}; use one of {', '.join(MODES)} or mixed")
        if not 0 < self.colour_cast[0] <= self.colour_cast[1]:
            raise ValueError(f"colour_cast={self.colour_cast} must satisfy 0 < low <= high")
        if not 0 < self.white_balance[0] <= self.white_balance[1]:
            raise ValueError(f"white_balance={self.white_balance} must satisfy 0 < low <= high")
        if self.jpeg_quality is not None and not 1 <= self.jpeg_quality[0] <= self.jpeg_quality[1] <= 100:
            raise ValueError(f"jpeg_quality={self.jpeg_quality} must satisfy 1 <= low <= high <= 100")
        for name, bounds in (("exposure", self.exposure), ("gamma", self.gamma), ("low_light.exposure", self.low_light.exposure),
                             ("low_light.gamma", self.low_light.gamma), ("over_exposure.exposure", self.over_exposure.exposure),
                             ("over_exposure.gamma", self.over_exposure.gamma)):
            kind = name.rsplit(".", 1)[-1]
            if bounds is not None and not is_valid_range(bounds, kind):
                raise ValueError(f"degrade.{name}={bounds} must satisfy {range_rule(kind)}")
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
    """Drawn parameters, broadcastable to the images' batch shape [...] (float64); cast [..., 3]
    linear gains (green 1); jpeg_quality [...] (None: no JPEG); quantize: round to 8 bits."""

    exposure: torch.Tensor
    gamma: torch.Tensor
    shot: torch.Tensor | None = None
    read: torch.Tensor | None = None
    cast: torch.Tensor | None = None
    jpeg_quality: torch.Tensor | None = None
    quantize: bool = False

    def as_dict(self, index: tuple[int, ...] = ()) -> dict:
        """Plain numbers of one image (for logs and JSON)."""
        values = {"exposure": self.exposure, "gamma": self.gamma, "shot_noise": self.shot, "read_noise": self.read,
                  "jpeg_quality": self.jpeg_quality}
        found = {name: float(v[index]) for name, v in values.items() if v is not None}
        if self.cast is not None:
            found["colour_cast"] = [float(g) for g in self.cast[index]]
        if self.quantize or self.jpeg_quality is not None:
            found["bits"] = 8
        return found


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
    parameters = DegradationParameters(exposure, gamma, quantize=degradation.quantize)
    if degradation.noise:
        noise = SENSOR_NOISE
        log_shot = _uniform(shape, *(math.log(v) for v in noise.shot_range), generator)
        jitter = noise.read_jitter * torch.randn(shape, generator=generator, device=generator.device, dtype=torch.float64)
        log_read = noise.read_slope * log_shot + noise.read_intercept + jitter
        parameters.shot, parameters.read = log_shot.exp(), log_read.exp()
    if degradation.colour_cast != (1.0, 1.0):
        # log-uniform, so a gain and its inverse are equally likely
        low, high = (math.log(v) for v in degradation.colour_cast)
        cast = _uniform((*shape, 3), low, high, generator).exp()
        cast[..., 1] = 1.0
        parameters.cast = cast
    if degradation.jpeg_quality is not None:
        low, high = degradation.jpeg_quality
        parameters.jpeg_quality = torch.randint(low, high + 1, shape, generator=generator, device=generator.device).double()
    return parameters


def _jpeg(images: torch.Tensor, quality: torch.Tensor) -> torch.Tensor:
    """sRGB images [..., 3, H, W] through OpenCV's JPEG encoder and decoder at `quality`
    (broadcast over the batch dims), back as float in [0, 1]."""
    batch_shape = images.shape[:-3]
    qualities = quality.expand(batch_shape).reshape(-1).tolist()
    flat = images.reshape(-1, *images.shape[-3:])
    decoded = []
    for image, level in zip(flat, qualities):
        pixels = (image.permute(1, 2, 0).cpu().numpy() * 255).round().clip(0, 255).astype(np.uint8)
        ok, encoded = cv2.imencode(".jpg", pixels[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(level)])
        if not ok:
            raise RuntimeError(f"OpenCV could not encode a JPEG at quality {level}")
        back = cv2.imdecode(encoded, cv2.IMREAD_COLOR)[..., ::-1].copy()
        decoded.append(torch.from_numpy(back).permute(2, 0, 1))
    return (torch.stack(decoded).reshape(images.shape).to(images.device, images.dtype) / 255.0)


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
    if parameters.cast is not None:
        exposed = exposed * parameters.cast.to(device=images.device, dtype=images.dtype).expand(
            (*images.shape[:-3], 3))[..., None, None]
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
    encoded = linear_to_srgb(toned.clamp(0.0, 1.0))
    if parameters.jpeg_quality is not None:
        return _jpeg(encoded, parameters.jpeg_quality)
    if parameters.quantize:
        return torch.round(encoded * 255.0) / 255.0
    return encoded


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
