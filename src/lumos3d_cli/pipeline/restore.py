"""Restore a scene from degraded photos in one forward pass: select views, prepare them for the
network, predict cameras, depth and fused Gaussians, and render every input view back at the
input's full resolution."""

from __future__ import annotations

import hashlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.checkpoints import BUNDLED_MODELS, bundled_weights_path
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.io.images import ImageBatch
from lumos3d_cli.model.loading import load_model
from lumos3d_cli.model.lumos3d import GaussianCounts, Lumos3D
from lumos3d_cli.model.preprocess import prepare_images
from lumos3d_cli.pipeline.presets import RestorePreset
from lumos3d_cli.pipeline.sampling_filter import apply_sampling_filter
from lumos3d_cli.render.render import render

logger = logging.getLogger(__name__)


@dataclass
class RestoredScene:
    """gaussians: the fused scene (world = first selected view's camera frame); cameras at the
    input resolution; restored [V, 3, H, W] renders at the input cameras; inputs [V, 3, H, W];
    selected: indices into the input batch; timings in seconds per stage."""

    gaussians: Gaussians
    cameras: Cameras
    restored: torch.Tensor
    inputs: torch.Tensor
    selected: list[int]
    counts: GaussianCounts
    network_size: tuple[int, int]
    timings: dict[str, float] = field(default_factory=dict)


def resolve_checkpoint(checkpoint: Path | str | None, mode: str) -> Path:
    """The given checkpoint, or the bundled model of `mode` (InputError naming what is missing)."""
    if checkpoint is not None:
        path = Path(checkpoint)
        if not path.exists():
            raise InputError(f"--checkpoint {path}: no such file or folder")
        return path
    path = bundled_weights_path(BUNDLED_MODELS[mode])
    if not path.is_file():
        raise InputError(f"no bundled {mode} model ({path.name} is missing from the package); pass --checkpoint PATH")
    return path


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for item in files:
        with open(item, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


def load_restoration_model(checkpoint: Path, device: str) -> Lumos3D:
    if device == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: CUDA is not available on this machine; use --device cpu")
    return load_model(checkpoint, device=device)


def even_subset(count: int, limit: int, required: list[int] = ()) -> list[int]:
    """`limit` indices of range(count) spread evenly, always including `required`."""
    if count <= limit:
        return list(range(count))
    required = sorted(set(required))
    if len(required) > limit:
        raise InputError(f"{len(required)} required views exceed the limit of {limit}; raise --max-views")
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


def run_network(
    model: Lumos3D, images: torch.Tensor, preset: RestorePreset, fuse_views: torch.Tensor | None = None
):
    """images [V, 3, H, W] at input size -> (model output, PreparedImages)."""
    size = preset.network_image_size(model.architecture.image_size, model.architecture.patch_size)
    prepared = prepare_images(images, size, model.architecture.patch_size)
    device = next(model.parameters()).device
    with torch.no_grad():
        output = model(prepared.images[None].to(device), voxel_size=model.architecture.voxel_size * preset.voxel_scale,
                       fuse_views=fuse_views.to(device) if fuse_views is not None else None)
    return output, prepared


def scene_gaussians(output) -> Gaussians:
    """The fused Gaussians of the (single) scene on the CPU, with the network's pixel grid baked
    in (`apply_sampling_filter`) so that they render well at any resolution."""
    cameras = output.cameras(0)
    network_cameras = Cameras(cameras.extrinsics.cpu(), cameras.intrinsics.cpu(), cameras.sizes)
    return apply_sampling_filter(output.gaussians[0].detach().to(device="cpu"), network_cameras)


def input_cameras(output, prepared, names: list[str]) -> Cameras:
    """The predicted cameras mapped back to the input images' pixels."""
    intrinsics = prepared.intrinsics_to_original(output.intrinsics[0].detach().double().cpu())
    return Cameras(output.extrinsics[0].detach().double().cpu(), intrinsics, [prepared.original_size] * len(names), names)


def render_at(gaussians: Gaussians, cameras: Cameras, sh_degree: int | None, on_view: Callable[[], None] | None = None) -> torch.Tensor:
    """[V, 3, H, W] renders, one view at a time (bounded memory at full resolution)."""
    degree = gaussians.sh_degree if sh_degree is None else min(sh_degree, gaussians.sh_degree)
    views = []
    for index in range(len(cameras)):
        with torch.no_grad():
            views.append(render(gaussians, cameras[index], sh_degree=degree).images[0].cpu())
        if on_view is not None:
            on_view()
    return torch.stack(views)


def restore_scene(
    batch: ImageBatch, model: Lumos3D, preset: RestorePreset, max_views: int | None = None,
    on_stage: Callable[[str], None] | None = None, on_view: Callable[[], None] | None = None,
) -> RestoredScene:
    """The whole job on one scene. `max_views` (default: the preset's) caps the views that go
    through the network; they are chosen evenly and every input is still rendered."""
    timings: dict[str, float] = {}
    limit = max_views or preset.max_views
    selected = even_subset(len(batch.paths), limit)
    if len(selected) < len(batch.paths):
        logger.warning("%d views given; the network sees %d of them, chosen evenly (raise --max-views to use more)",
                       len(batch.paths), len(selected))
    started = time.perf_counter()
    if on_stage:
        on_stage("network")
    output, prepared = run_network(model, batch.images[selected], preset)
    timings["network"] = time.perf_counter() - started
    gaussians = scene_gaussians(output)
    if preset.sh_degree is not None and preset.sh_degree < gaussians.sh_degree:
        gaussians = Gaussians(gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities,
                              gaussians.sh[:, : (preset.sh_degree + 1) ** 2].contiguous())
    names = [batch.paths[i].name for i in selected]
    cameras = input_cameras(output, prepared, names)
    if on_stage:
        on_stage("render")
    started = time.perf_counter()
    restored = render_at(gaussians, cameras, preset.sh_degree, on_view)
    timings["render"] = time.perf_counter() - started
    return RestoredScene(
        gaussians, cameras, restored, batch.images[selected], selected, output.counts[0],
        prepared.network_size, timings,
    )
