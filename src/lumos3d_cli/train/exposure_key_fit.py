"""Fitting the exposure key predictor (`model.appearance.exposure_key`) on well-exposed photos.

A well-exposed photo is its own target: brought to the fixed key, its features are what the
restore will see, and the stops back to the photo's own exposure are what the predictor should
say (a darker version of the photo needs the same correction plus its own darkening, which the
key already removes). So a sample is one reference photo, or one scene's views pooled, and the
fit is weighted ridge regression in closed form on standardised features.
"""

from __future__ import annotations

import torch

from lumos3d_cli.io.colour import srgb_to_linear
from lumos3d_cli.model.appearance.exposure_key import ExposureKeyModel
from lumos3d_cli.model.appearance.exposure_prior import EXPOSURE_KEY, features_at_key, stops_to_key


def reference_sample(views: torch.Tensor) -> tuple[torch.Tensor, float]:
    """views [N, 3, H, W] sRGB of one well-exposed scene (or one photo, N = 1) -> (its key
    features [F] float64, its offset from the fixed key in stops: minus the gain that brings it
    to the key)."""
    linear = srgb_to_linear(views.double().clamp(0.0, 1.0))
    to_key = float(stops_to_key(linear[None], EXPOSURE_KEY)[0])
    return features_at_key(linear, to_key), -to_key


def fit_exposure_key(features: torch.Tensor, offsets: torch.Tensor, weights: torch.Tensor | None = None,
                     ridge: float = 10.0) -> ExposureKeyModel:
    """features [M, F], offsets [M] (stops), weights [M] (each sample's share; default equal) ->
    the ridge regression minimising sum w (offset - prediction)^2 + ridge * |coefficients|^2 on
    features standardised by their weighted mean and deviation (the intercept is not penalised;
    the weights are normalised to sum to M, so `ridge` is on the scale of one sample)."""
    if features.dim() != 2 or offsets.shape != features.shape[:1]:
        raise ValueError(f"features [M, F] and offsets [M] expected, got {tuple(features.shape)} and {tuple(offsets.shape)}")
    if ridge < 0:
        raise ValueError(f"ridge must be >= 0, got {ridge}")
    count = features.shape[0]
    x, y = features.double(), offsets.double()
    w = torch.ones(count, dtype=torch.float64) if weights is None else weights.double()
    if not bool((w >= 0).all()) or float(w.sum()) <= 0:
        raise ValueError("sample weights must be >= 0 and not all 0")
    w = w * count / w.sum()
    mean = (w[:, None] * x).sum(0) / count
    scale = ((w[:, None] * (x - mean) ** 2).sum(0) / count).sqrt()
    scale = torch.where(scale > 1e-9, scale, torch.ones_like(scale))  # a constant feature: no information
    design = torch.cat([torch.ones(count, 1, dtype=torch.float64), (x - mean) / scale], dim=1)
    penalty = ridge * torch.eye(design.shape[1], dtype=torch.float64)
    penalty[0, 0] = 0.0
    solution = torch.linalg.solve(design.T @ (w[:, None] * design) + penalty, design.T @ (w * y))
    return ExposureKeyModel(mean, scale, solution[1:].contiguous(), float(solution[0]))
