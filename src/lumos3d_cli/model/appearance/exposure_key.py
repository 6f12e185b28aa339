"""The exposure a scene's content asks for: how many stops brighter or darker than the fixed key
(mean sRGB 0.45) its well-exposed photo is, predicted from what the scene shows.

A white wall, a night street and a dark sofa do not share one brightness: a photographer (or a
camera's matrix metering) exposes a scene of a black background and a lit object darker on
average than a scene of pale walls. Once a scene is brought to the fixed key, the shape of what
is left, that is how its brightness is spread (quantiles, near-black and near-white fractions),
where it lies (sky at the top, a subject in the centre) and how colourful it is, says part of
this. The predictor is a ridge regression on those features (fitted by
`train/exposure_key_fit.py` on the normal-light training scenes and the SICE training brackets'
chosen references, `benchmarks/exposure_key.py`), small enough to read in the model card, and
it predicts the scene's offset from the key in stops (log2 of mean linear luminance).

The features are computed on views already brought to the key, so they do not depend on how
bright the input was; `model.appearance.exposure_prior` does that and adds the offset to the
gain.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn.functional as F

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.colour import linear_to_srgb, luminance, srgb_to_linear
from lumos3d_cli.model.bundled_models import bundled_weights_path

KEY_FEATURE_NAMES = (
    "luminance quantile 0.02", "luminance quantile 0.10", "luminance quantile 0.25", "luminance median",
    "luminance quantile 0.75", "luminance quantile 0.90", "luminance quantile 0.98",
    "near-black fraction", "near-white fraction", "top third minus bottom third", "centre minus whole", "colourfulness",
)  # fmt: skip
_QUANTILES = (0.02, 0.10, 0.25, 0.50, 0.75, 0.90, 0.98)
NEAR_BLACK, NEAR_WHITE = 0.05, 0.95  # sRGB luminance: crushed shadows / blown highlights at the key
FEATURE_SIZE = 96  # views are averaged down to this long side: the layout of a scene, not its noise
MAX_OFFSET_STOPS = 2.0  # the prediction never moves a scene further than this from the key
_QUANTILE_SAMPLES = 2**20  # torch.quantile's input limit is 2^24; a strided sample beyond this
BUNDLED_KEY_MODEL = bundled_weights_path("exposure-key")


def key_features(views_at_key: torch.Tensor) -> torch.Tensor:
    """views_at_key [N, 3, H, W] sRGB in [0, 1] (one scene's views, brought to the fixed key)
    -> [len(KEY_FEATURE_NAMES)] float64: the scene's key features, its views pooled."""
    if views_at_key.dim() != 4 or views_at_key.shape[1] != 3:
        raise ValueError(f"views must be [N, 3, H, W], got {tuple(views_at_key.shape)}")
    views = views_at_key.detach().double().clamp(0.0, 1.0)
    height, width = views.shape[-2:]
    scale = min(1.0, FEATURE_SIZE / max(height, width))
    if scale < 1.0:  # averaging in linear light, as a smaller photo of the scene would be
        size = (max(1, round(height * scale)), max(1, round(width * scale)))
        views = linear_to_srgb(F.adaptive_avg_pool2d(srgb_to_linear(views), size))
    grey = linear_to_srgb(luminance(srgb_to_linear(views)))[:, 0]  # [N, h, w]
    pooled = grey.flatten()
    pooled = pooled[:: max(1, -(-pooled.numel() // _QUANTILE_SAMPLES))]
    quantiles = torch.quantile(pooled, pooled.new_tensor(_QUANTILES))
    rows = grey.shape[1]
    third = max(1, rows // 3)
    top_minus_bottom = (grey[:, :third].mean(dim=(1, 2)) - grey[:, -third:].mean(dim=(1, 2))).mean()
    centre = grey[:, _middle_half(rows), _middle_half(grey.shape[2])]
    centre_minus_whole = (centre.mean(dim=(1, 2)) - grey.mean(dim=(1, 2))).mean()
    colourfulness = (views.amax(dim=1) - views.amin(dim=1)).mean()
    return torch.cat([quantiles, torch.stack([
        (pooled < NEAR_BLACK).double().mean(), (pooled > NEAR_WHITE).double().mean(),
        top_minus_bottom, centre_minus_whole, colourfulness])])


def _middle_half(length: int) -> slice:
    """The middle half of an axis of `length` (at least one element)."""
    start = length // 4
    return slice(start, max(start + 1, 3 * length // 4))


@dataclass(frozen=True)
class ExposureKeyModel:
    """A ridge regression from standardised key features to the offset from the key in stops:
    offset = intercept + sum(coefficients * (features - feature_mean) / feature_scale), clamped
    to +-MAX_OFFSET_STOPS. Tensors are float64 [len(KEY_FEATURE_NAMES)]."""

    feature_mean: torch.Tensor
    feature_scale: torch.Tensor
    coefficients: torch.Tensor
    intercept: float

    def __post_init__(self) -> None:
        count = len(KEY_FEATURE_NAMES)
        for name in ("feature_mean", "feature_scale", "coefficients"):
            value = getattr(self, name)
            if value.shape != (count,) or not bool(torch.isfinite(value).all()):
                raise ValueError(f"exposure key model: {name} must be {count} finite numbers, got {tuple(value.shape)}")
        if not bool((self.feature_scale > 0).all()) or not torch.isfinite(torch.tensor(self.intercept)):
            raise ValueError("exposure key model: feature scales must be positive and the intercept finite")

    def offset_stops(self, features: torch.Tensor) -> torch.Tensor:
        """features [..., F] (any device) -> [...] float64 on the CPU: the stops from the fixed key
        to the scene's predicted exposure (positive: a brighter scene)."""
        standardised = (features.detach().to("cpu", torch.float64) - self.feature_mean) / self.feature_scale
        offset = self.intercept + standardised @ self.coefficients
        return offset.clamp(-MAX_OFFSET_STOPS, MAX_OFFSET_STOPS)

    def save(self, path: Path | str) -> None:
        from safetensors.torch import save_file

        save_file({"feature_mean": self.feature_mean, "feature_scale": self.feature_scale,
                   "coefficients": self.coefficients, "intercept": torch.tensor([self.intercept], dtype=torch.float64)},
                  str(path), metadata={"features": ",".join(KEY_FEATURE_NAMES)})

    @classmethod
    def load(cls, path: Path | str) -> ExposureKeyModel:
        """A model written by `save`; InputError naming the file when it is not one."""
        from safetensors import safe_open

        try:
            with safe_open(str(path), framework="pt") as weights:
                features = (weights.metadata() or {}).get("features", "")
                tensors = {name: weights.get_tensor(name).double() for name in weights.keys()}
            if features != ",".join(KEY_FEATURE_NAMES):
                raise ValueError("it was fitted on other features")
            return cls(tensors["feature_mean"], tensors["feature_scale"], tensors["coefficients"],
                       float(tensors["intercept"][0]))
        except (OSError, KeyError, ValueError, RuntimeError) as error:
            raise InputError(f"{path}: not an exposure key model of this version ({error}); reinstall lumos3d") from None


@functools.cache
def bundled_key_model() -> ExposureKeyModel:
    """The predictor shipped in lumos3d_cli/weights/exposure-key.safetensors (read once)."""
    return ExposureKeyModel.load(BUNDLED_KEY_MODEL)
