"""The network's part of a job: which views it sees, at which size, and its one forward pass
(cameras, depth, per-pixel Gaussian parameters), before any geometry is registered."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.field_of_view import plausible_intrinsics
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.model.appearance.exposure_key import bundled_key_model
from lumos3d_cli.model.appearance.exposure_prior import exposure_prior_stops, prior_strength
from lumos3d_cli.model.appearance.operator import AppearanceOperator
from lumos3d_cli.model.appearance.photo_restoration import frames_without_content
from lumos3d_cli.model.lumos3d import Lumos3D, Lumos3DPrediction
from lumos3d_cli.model.preprocess import PreparedImages, prepare_images
from lumos3d_cli.pipeline.presets import RestorePreset


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
    (`geometry.field_of_view.plausible_intrinsics`; None: none), and `replaced_fields_of_view`
    what was predicted for them, at the photos' own size (for a warning where those cameras are
    used)."""

    prediction: Lumos3DPrediction
    prepared: PreparedImages
    exposure_stops: float | None = None
    replaced_cameras: torch.Tensor | None = None
    replaced_fields_of_view: str | None = None

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
    described = None
    if bool(replaced.any()):
        described = _predicted_fields_of_view(prediction.intrinsics[0][replaced], prepared.network_size,
                                              stretch[replaced.cpu()] if stretch is not None else None)
        prediction = replace(prediction, intrinsics=intrinsics[None])
    return NetworkPass(prediction, prepared, exposure_stops, replaced.cpu(), described)


def _predicted_fields_of_view(intrinsics: torch.Tensor, size: tuple[int, int], stretch: torch.Tensor | None) -> str:
    """'51.2x43 degrees across x down, pixels 2.6 times as wide as tall' for the first few of the
    predicted cameras `intrinsics` [R, 3, 3] of network images of `size`: fields of view are the
    same at the photo's own size; the pixels' shape is given there (`stretch` [R], as
    `plausible_intrinsics` takes it), since a lens's are square while a plausible field of view
    across and down can still mean stretched pixels (a portrait photo seen as a landscape one)."""
    width, height = size
    fx, fy = intrinsics[:5, 0, 0].double().cpu(), intrinsics[:5, 1, 1].double().cpu()
    own = torch.ones_like(fx) if stretch is None else stretch[:5].double().cpu()
    across, down = (torch.rad2deg(2 * torch.atan(side / 2 / focal)) for side, focal in ((width, fx), (height, fy)))
    return ", ".join(f"{a:.3g}x{d:.3g} degrees across x down, pixels {ratio:.2g} times as wide as tall"
                     for a, d, ratio in zip(across.tolist(), down.tolist(), (fy / (fx * own)).tolist()))
