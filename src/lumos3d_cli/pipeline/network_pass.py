"""The network's part of a job: which views it sees, at which size, and its one forward pass
(cameras, depth, per-pixel Gaussian parameters), before any geometry is registered."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.field_of_view import FALLBACK_FOV_DEGREES, plausible_intrinsics
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.model.appearance.exposure_key import bundled_key_model
from lumos3d_cli.model.appearance.exposure_prior import exposure_prior_stops, prior_strength
from lumos3d_cli.model.appearance.operator import AppearanceOperator
from lumos3d_cli.model.appearance.photo_restoration import frames_without_content
from lumos3d_cli.model.lumos3d import Lumos3D, Lumos3DPrediction
from lumos3d_cli.model.preprocess import PreparedImages, prepare_images
from lumos3d_cli.pipeline.presets import RestorePreset

logger = logging.getLogger(__name__)


def even_subset(count: int, limit: int, required: list[int] = ()) -> list[int]:
    """`limit` indices of range(count) spread evenly, always including `required`."""
    if count <= limit:
        return list(range(count))
    required = sorted(set(required))
    if len(required) > limit:
        raise InputError(f"{limit}: {len(required)} views must go through the network; raise it", parameter="max_views")
    chosen = set(required)
    for position in torch.linspace(0, count - 1, limit).round().long().tolist():
        if len(chosen) >= limit:
            break
        chosen.add(position)
    for index in range(count):  # rounding can leave gaps when many are required
        if len(chosen) >= limit:
            break
        chosen.add(index)
    return sorted(chosen)


@dataclass
class NetworkPass:
    """The forward pass over the selected views: `prediction` (batch of one scene), the prepared
    images (network size, and the map between network and photo pixels), the gain in stops the
    exposure prior added to the predicted operator (None: the model predicts no operator) and
    `replaced_cameras` [S] bool: the views whose predicted field of view no lens has was replaced
    (`geometry.field_of_view.plausible_intrinsics`; None: none)."""

    prediction: Lumos3DPrediction
    prepared: PreparedImages
    exposure_stops: float | None = None
    replaced_cameras: torch.Tensor | None = None

    @property
    def network_size(self) -> tuple[int, int]:
        """(width, height) of the network images."""
        return self.prepared.network_size

    def network_cameras(self, names: list[str]) -> Cameras:
        """The network's own cameras of the selected views, at the photos' resolution."""
        intrinsics = self.prepared.intrinsics_to_original(self.prediction.intrinsics[0].detach().double().cpu())
        extrinsics = self.prediction.extrinsics[0].detach().double().cpu()
        return Cameras(extrinsics, intrinsics, [self.prepared.original_size] * len(names), names)

    def to_network(self, cameras: Cameras) -> Cameras:
        """Cameras at the photos' resolution -> the same cameras in network pixels."""
        intrinsics = self.prepared.intrinsics_to_network(cameras.intrinsics.double())
        return Cameras(cameras.extrinsics.double(), intrinsics, [self.network_size] * len(cameras), cameras.names)


def network_image_size(model: Lumos3D, preset: RestorePreset) -> int:
    return preset.network_image_size(model.architecture.image_size, model.architecture.patch_size)


def _appearance_without(model: Lumos3D, images: torch.Tensor, empty: Sequence[int]) -> AppearanceOperator:
    """images [1, V, 3, h, w] (network size) -> the restoration operator predicted from the views not
    in `empty` (all black or saturated photos: one white photo among four darkened the others by a
    quarter, 4 dB, as the illumination head read it as part of the scene), for all V views; the
    empty views get no local correction (their restoration stays black or white)."""
    keep = [view for view in range(images.shape[1]) if view not in set(empty)]
    operator = model.predict_appearance(images[:, keep])
    local = operator.local_log2_gain
    if local is not None:
        full = local.new_zeros(local.shape[0], images.shape[1], *local.shape[2:])
        full[:, keep] = local
        local = full
    return replace(operator, local_log2_gain=local)


def run_network(model: Lumos3D, images: torch.Tensor, preset: RestorePreset, mode: str = "low-light",
                empty_views: Sequence[int] | None = None, stretch: torch.Tensor | None = None) -> NetworkPass:
    """images [V, 3, H, W] at the photos' size -> the network's predictions for them; a view
    whose predicted field of view no lens has gets a typical one (`geometry.field_of_view`), and
    a predicted restoration operator is followed by the exposure prior
    (`model.appearance.exposure_prior`) at the preset's strength or the `mode`'s own, metered
    without the `empty_views` (all black or saturated; None: judged here, on `images`).
    `stretch` [V]: each photo's own width over `images`' width, divided by its own height over
    `images`' height (a photo of another aspect ratio stretched to them; None: none was), so that
    its camera is judged at its own size (`geometry.field_of_view.plausible_intrinsics`)."""
    prepared = prepare_images(images, network_image_size(model, preset), model.architecture.patch_size)
    device = next(model.parameters()).device
    with torch.no_grad():
        prediction = model.predict(prepared.images[None].to(device))
    black, saturated = [], []
    if prediction.appearance is not None:
        if empty_views is None:  # on the working photos: the network's resized copies have more levels
            black, saturated = frames_without_content(images)
        else:
            black, saturated = list(empty_views), []
        empty = sorted({*black, *saturated})
        if 0 < len(empty) < images.shape[0]:
            with torch.no_grad():
                appearance = _appearance_without(model, prepared.images[None].to(device), empty)
            prediction = replace(prediction, appearance=appearance)
    source = model.provenance.get("path", "the model's weights")
    prediction.require_finite(f"{source} gives NaN/Inf on these photos: damaged or diverged weights; use another "
                              "checkpoint")
    exposure_stops = None
    if prediction.appearance is not None:
        stops = exposure_prior_stops(prediction.appearance, prepared.images[None].to(device),
                                     prior_strength(mode, preset.exposure_prior),
                                     key_model=bundled_key_model() if preset.exposure_key == "content" else None,
                                     unmetered=[{*black, *saturated}])
        prediction, exposure_stops = replace(prediction, appearance=prediction.appearance.with_gain(stops)), float(stops[0])
    intrinsics, replaced = plausible_intrinsics(prediction.intrinsics[0], prepared.network_size, stretch)
    if bool(replaced.any()):
        predicted = prediction.intrinsics[0][replaced]
        width, height = prepared.network_size
        degrees = [f"{across:.3g}x{down:.3g}" for across, down in zip(
            torch.rad2deg(2 * torch.atan(width / 2 / predicted[:, 0, 0])).tolist()[:5],
            torch.rad2deg(2 * torch.atan(height / 2 / predicted[:, 1, 1])).tolist()[:5])]
        # one photo has no structure-from-motion, and its restored view does not depend on its camera
        advice = "" if len(replaced) == 1 else " (give --poses or use structure-from-motion for exact cameras)"
        logger.warning("the network predicted a field of view no lens has (%s degrees across x down) for %d of %d "
                       "view(s); using square pixels there, at the longer side's field of view where it is plausible, "
                       "else %g degrees%s", ", ".join(degrees), int(replaced.sum()), len(replaced), FALLBACK_FOV_DEGREES,
                       advice)
        prediction = replace(prediction, intrinsics=intrinsics[None])
    return NetworkPass(prediction, prepared, exposure_stops, replaced.cpu())
