"""The network's part of a job: which views it sees, at which size, and its one forward pass
(cameras, depth, per-pixel Gaussian parameters), before any geometry is registered."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.cameras import Cameras
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
    """The forward pass over the selected views: `prediction` (batch of one scene) and the
    prepared images (network size, and the map between network and photo pixels)."""

    prediction: Lumos3DPrediction
    prepared: PreparedImages

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


def run_network(model: Lumos3D, images: torch.Tensor, preset: RestorePreset) -> NetworkPass:
    """images [V, 3, H, W] at the photos' size -> the network's predictions for them."""
    prepared = prepare_images(images, network_image_size(model, preset), model.architecture.patch_size)
    device = next(model.parameters()).device
    with torch.no_grad():
        prediction = model.predict(prepared.images[None].to(device))
    return NetworkPass(prediction, prepared)
