"""The exposure prior: after the illumination head, pull each scene's overall brightness part of
the way towards a fixed key, the way a camera's auto-exposure meters a frame.

A dark photo cannot say how bright its scene "should" be, and the bundled heads guess it with
an error of their own (on the held-out SICE brackets their output over the target's brightness
spreads from 0.73 to 1.33). A fixed key guesses it with an independent error; the geometric mean
of the two, weighted by `strength`, is closer than either (benchmarks/exposure_prior.py, which
chose the strength on the brackets' training split and confirmed it on the held-out ones). The
key, mean sRGB 0.45, is the level the bracket pairing rule calls well exposed
(`data.brackets.WELL_EXPOSED_MEAN`), which the heads were trained to reach.

The gain is one number per scene in linear light, applied after the curve (so it keeps the
head's colours, tone and per-view local grids), and bounded: a black scene gets none, and a
brightening gain never pushes more than MAX_NEWLY_CLIPPED of the pixels into clipping. The mean
of a night street is its dark walls; metering it alone blew the lit bus of
`lowlight_single/003.jpg` out to orange (+1.7 stops); highlight protection, as a camera's
metering has, leaves it 0.2 stop. It costs the held-out brackets 0.2 dB of the prior's gain.

The key itself can come from the scene's content (`model.appearance.exposure_key`): the scene is
metered to the fixed key, and a predictor reads from what it shows how many stops brighter or
darker its well-exposed photo would be (a black background around a lit object, a pale wall).
"""

from __future__ import annotations

import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.io.colour import linear_to_srgb, srgb_to_linear
from lumos3d_cli.model.appearance.exposure_key import ExposureKeyModel, key_features
from lumos3d_cli.model.appearance.operator import AppearanceOperator
from lumos3d_cli.model.appearance.photo_restoration import BLACK_LEVEL, WHITE_LEVEL, frames_without_content

EXPOSURE_KEY = 0.45  # mean sRGB of a well-exposed frame (data.brackets.WELL_EXPOSED_MEAN)
# The strength of each mode, chosen on the mean over the development sources (benchmarks/
# appearance_dev.py; the model card's exposure-prior table): low light 0.75 (first chosen on the
# SICE training split, benchmarks/exposure_prior.py, and kept there); over-exposure 0.5: of 0,
# 0.25, 0.5 and 0.75 its mean SSIM is the highest (0.708, tied with 0.75), its mean absolute
# brightness error the lowest (0.19 stop) and its mean PSNR 0.41 dB above 0.75's.
EXPOSURE_PRIOR_STRENGTH = {"low-light": 0.75, "over-exposure": 0.5}
MAX_PRIOR_STOPS = 3.0  # the key never moves a scene further than this (a frame of nearly nothing)
MAX_NEWLY_CLIPPED = 0.01  # brightening may clip at most 1 % more of a scene's pixels
_METERING_SAMPLES = 2**18  # values a scene is metered on (a strided sample): its mean to ~1e-3
_BISECTION_STEPS = 30  # 6 stops / 2^30: far below one 8-bit step


def stops_to_key(restored_linear: torch.Tensor, key: float = EXPOSURE_KEY, max_stops: float = MAX_PRIOR_STOPS) -> torch.Tensor:
    """restored_linear [B, N, 3, H, W] (the scenes' restored images in linear light, not clipped)
    -> [B] float32 log2 gains g in [-max_stops, max_stops] such that the mean over each scene of
    sRGB(clip(2^g x)) is `key`; the bound where no gain within it reaches the key, and 0 for a
    scene that holds nothing to meter (every value within one 8-bit step of black, or of white).

    The clipped mean rises monotonically with the gain, so bisection in stops finds it. Larger
    scenes are metered on an even stride of _METERING_SAMPLES of their values.
    """
    stops, empty = _metered(restored_linear, key, max_stops)
    return torch.where(empty, torch.zeros_like(stops), stops).float()


def _metered(restored_linear: torch.Tensor, key: float, max_stops: float) -> tuple[torch.Tensor, torch.Tensor]:
    """restored_linear [B, N, 3, H, W] -> (the gains of stops_to_key before scenes without content
    are set to 0 [B] float64, which scenes hold nothing to meter [B] bool)."""
    if restored_linear.dim() != 5:
        raise ValueError(f"restored images must be [B, N, 3, H, W], got {tuple(restored_linear.shape)}")
    flat = _strided(restored_linear.detach().flatten(1)).double().clamp_min(0.0)
    low = torch.full((flat.shape[0],), -max_stops, dtype=torch.float64, device=flat.device)
    high = torch.full_like(low, max_stops)
    for _ in range(_BISECTION_STEPS):
        middle = (low + high) / 2
        brightness = linear_to_srgb((flat * torch.exp2(middle)[:, None]).clamp(0.0, 1.0)).mean(dim=1)
        below = brightness < key
        low = torch.where(below, middle, low)
        high = torch.where(below, high, middle)
    # a scene with nothing to meter: no pixel above one 8-bit step of black, or none below white (the
    # photos that are empty themselves, photo_restoration.frames_without_content, are left out before)
    encoded = linear_to_srgb(flat.clamp(0.0, 1.0))
    empty = (encoded.amax(dim=1) <= BLACK_LEVEL) | (encoded.amin(dim=1) >= WHITE_LEVEL)
    return (low + high) / 2, empty


def stops_to_content_key(restored_linear: torch.Tensor, key_model: ExposureKeyModel, key: float = EXPOSURE_KEY,
                         max_stops: float = MAX_PRIOR_STOPS) -> torch.Tensor:
    """restored_linear [B, N, 3, H, W] -> [B] float32 log2 gains in [-max_stops, max_stops]: the
    gain to the fixed `key` (stops_to_key) plus the offset `key_model` predicts from each scene
    seen at that key; 0 for a scene that holds nothing to meter."""
    to_key, empty = _metered(restored_linear, key, max_stops)
    offsets = torch.stack([key_model.offset_stops(features_at_key(scene, float(gain)))
                           for scene, gain in zip(restored_linear.detach(), to_key)])
    gains = (to_key.cpu() + offsets).clamp(-max_stops, max_stops).to(to_key.device)
    return torch.where(empty, torch.zeros_like(gains), gains).float()


def features_at_key(views_linear: torch.Tensor, gain: float) -> torch.Tensor:
    """views_linear [N, 3, H, W] (one scene, linear light), the log2 gain that brings it to the
    key -> its key features [F] (`exposure_key.key_features` of sRGB(clip(2^gain x)))."""
    return key_features(linear_to_srgb((views_linear * 2.0**gain).clamp(0.0, 1.0)))


def highlight_headroom(restored_linear: torch.Tensor, newly_clipped: float = MAX_NEWLY_CLIPPED,
                       max_stops: float = MAX_PRIOR_STOPS) -> torch.Tensor:
    """restored_linear [B, N, 3, H, W] -> [B] float32 stops in [0, max_stops]: the largest gain that
    clips (any channel reaching 1) at most `newly_clipped` more of each scene's pixels than are
    clipped already."""
    peaks = restored_linear.detach().float().clamp_min(0.0).amax(dim=2).flatten(1)  # [B, pixels]
    peaks = _strided(peaks)
    clipped = (peaks >= 1.0).float().mean(dim=1)
    level = (1.0 - clipped - newly_clipped).clamp_min(0.0)
    brightest_kept = torch.stack([torch.quantile(row, float(q)) for row, q in zip(peaks, level)])
    headroom = -torch.log2(brightest_kept.clamp_min(2.0**-max_stops))
    return headroom.clamp(0.0, max_stops)


def exposure_prior_stops(operator: AppearanceOperator, images: torch.Tensor, strength: float,
                         key: float = EXPOSURE_KEY, key_model: ExposureKeyModel | None = None,
                         unmetered: list[set[int]] | None = None) -> torch.Tensor:
    """operator of B scenes, images [B, V, 3, H, W] sRGB (the network images it was predicted
    from; its local grids are for these V views) -> [B] the prior's gain in stops: `strength`
    times the stops that bring each scene's restored mean to `key`, or with `key_model` to the
    key its content predicts (0: the operator as it is; 1: the key alone decides the exposure),
    a brightening gain limited to the scene's `highlight_headroom`. `unmetered`: per scene, the
    views left out (all black or white); None: found in `images`, which a resize may have given
    levels the photos did not have (`photo_restoration.frames_without_content` on the photos
    themselves is exact)."""
    if not 0.0 <= strength <= 1.0:
        raise ValueError(f"exposure prior strength must be in [0, 1], got {strength}")
    if strength == 0.0:
        return torch.zeros(operator.batch, device=operator.curve_slopes.device)
    with torch.no_grad():
        restored = operator.apply_linear(srgb_to_linear(images.float().clamp(0.0, 1.0)))
        require_finite("restored images the exposure prior meters", restored,
                       "the restoration operator produced NaN/Inf (corrupt weights or an unstable input?)")
        gains = []
        for index, (scene, photos) in enumerate(zip(restored, images)):
            # a black or saturated photo records nothing of the scene's brightness: metered with
            # the others it would pull the whole scene's gain (one black frame beside three photos lifted
            # them by a quarter stop); a scene of nothing else gets no gain
            left_out = unmetered[index] if unmetered is not None else set().union(*frames_without_content(photos))
            metered = scene[[view for view in range(len(scene)) if view not in left_out]][None]
            if metered.shape[1] == 0:
                gains.append(torch.zeros(1, device=scene.device))
                continue
            to_key = stops_to_key(metered, key) if key_model is None else stops_to_content_key(metered, key_model, key)
            stops = strength * to_key
            gains.append(torch.where(stops > 0, torch.minimum(stops, highlight_headroom(metered)), stops))
        return torch.cat(gains)


def apply_exposure_prior(operator: AppearanceOperator, images: torch.Tensor, strength: float,
                         key: float = EXPOSURE_KEY, key_model: ExposureKeyModel | None = None) -> AppearanceOperator:
    """The operator followed by the gain of `exposure_prior_stops` (same arguments)."""
    return operator.with_gain(exposure_prior_stops(operator, images, strength, key, key_model))


def prior_strength(mode: str, strength: float | None = None) -> float:
    """`strength`, or the mode's own (EXPOSURE_PRIOR_STRENGTH) when it is None."""
    return EXPOSURE_PRIOR_STRENGTH[mode] if strength is None else strength


def _strided(values: torch.Tensor) -> torch.Tensor:
    """[B, n] -> [B, <= _METERING_SAMPLES] every k-th value (all of them when n is small enough)."""
    return values[:, :: max(1, -(-values.shape[1] // _METERING_SAMPLES))]
