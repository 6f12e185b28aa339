"""The evaluation protocol on LOM-layout scenes.

context: all views of the scene (capped by max_views, always including the test frames) go
through the network; the scene is rendered at the cameras of the test frames (from the geometry
source: structure-from-motion over every frame, or the network), at the photos' resolution
(500x375 for LOM), and compared with `high/`. Pixels no Gaussian covers are filled from the
render around them (render.hole_filling; never from the test photo) unless the preset's
`fill_unobserved` is off; the report gives the fraction filled per test view.
holdout: the same forward pass, but the test frames' pixel Gaussians are left out of the fused
scene, so the test views are novel views of a scene built from the others.
The blind auto-gamma baseline is scored on the same frames. When the scene's transforms files
give every view with a camera a reference, those cameras are scored too (eval/pose_accuracy.py).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch

from lumos3d_cli.data.lom import LomScene, lom_reference_extrinsics
from lumos3d_cli.errors import InputError
from lumos3d_cli.eval.metrics import auto_gamma
from lumos3d_cli.eval.pose_accuracy import PoseAccuracy, pose_accuracy
from lumos3d_cli.io.images import load_images
from lumos3d_cli.model.lumos3d import Lumos3D
from lumos3d_cli.pipeline.presets import RestorePreset
from lumos3d_cli.pipeline.quality import QualityMeter
from lumos3d_cli.pipeline.restore import render_views
from lumos3d_cli.pipeline.scene_stages import build_scene

logger = logging.getLogger(__name__)

PROTOCOLS = ("context", "holdout")


@dataclass
class SceneEvaluation:
    """Per test frame: metrics of ours and of the baseline; the images for the contact sheet
    (inputs, baseline, references [T, 3, H, W]; renders, ours, per frame [3, H, W]); the accuracy
    of the predicted cameras of all views used (None without reference cameras); the Gaussians
    the scene kept and its budget."""

    scene: str
    protocol: str
    views_used: int
    test_frames: list[str]
    ours: list[dict]
    baseline: list[dict]
    seconds: float
    inputs: torch.Tensor
    renders: list[torch.Tensor]
    baseline_images: torch.Tensor | None
    references: torch.Tensor
    pose: PoseAccuracy | None = None
    geometry: dict = field(default_factory=dict)
    gaussians: dict = field(default_factory=dict)  # kept and the budget the scene got
    uncovered: dict = field(default_factory=dict)  # the test views' pixels no Gaussian covered, and if filled


def _pose_accuracy(scene: LomScene, frames: list[str], predicted: torch.Tensor) -> PoseAccuracy | None:
    """predicted extrinsics [V, 3, 4] of `frames` scored against the scene's transforms."""
    if len(frames) < 2:
        return None
    reference = lom_reference_extrinsics(scene)
    missing = [f for f in frames if f not in reference]
    if missing:
        logger.info("%s: no reference camera for %s; camera accuracy not scored", scene.root, ", ".join(missing))
        return None
    return pose_accuracy(predicted, torch.stack([reference[f] for f in frames]))


@dataclass
class LomPhotos:
    """A scene's photos, read and checked: `degraded` [V, 3, H, W] (every frame, in the scene's
    order), `references` [T, 3, H, W] (the test frames' normal-light photos)."""

    degraded: torch.Tensor
    references: torch.Tensor


def _load_same_size(paths: list[Path], size: tuple[int, int] | None = None) -> torch.Tensor:
    """[N, 3, H, W], one per path; InputError naming the first photo whose size differs from the
    first's (or from `size`, width and height), or one that is not read as a photo: every frame
    after it would be scored against the next frame's photo."""
    batch = load_images(paths)
    left_out = [path for path in paths if path not in batch.paths]
    if left_out:  # io/scene_photos.py: the folder's manifest names it as an earlier restore's output
        raise InputError(f"{left_out[0]}: written by an earlier restore (its folder's .lumos3d-manifest.json says so), "
                         "not a photo of the scene; put the scene's own photo back")
    expected = batch.original_sizes[0] if size is None else size
    for path, found in zip(paths, batch.original_sizes):
        if found != expected:
            raise InputError(f"{path}: {found[0]}x{found[1]}, but the scene's photos are {expected[0]}x{expected[1]}; "
                             "a LOM scene's frames must share one size")
    return batch.images


def read_lom_photos(scene: LomScene) -> LomPhotos:
    """Decode and check a scene's photos (InputError naming a photo that cannot be read or is of
    another size): `eval` reads every scene's before it loads the model and evaluates the first."""
    degraded = _load_same_size([scene.degraded[f] for f in scene.frames])
    size = (degraded.shape[-1], degraded.shape[-2])
    return LomPhotos(degraded, _load_same_size([scene.reference[f] for f in scene.test], size))


def evaluate_lom_scene(
    scene: LomScene, model: Lumos3D, preset: RestorePreset, protocol: str, max_views: int, meter: QualityMeter,
    geometry: str = "auto", photos: LomPhotos | None = None, with_baseline: bool = True,
) -> SceneEvaluation:
    """One scene under `protocol` with cameras from `geometry` (see pipeline.scene_stages.build_scene);
    every frame of the scene takes part in the registration, `max_views` of them (always the test
    frames) go through the network. `photos`: the scene's, already read (`read_lom_photos`).
    Without `with_baseline` the gamma curve is neither computed nor scored (empty `baseline`)."""
    if protocol not in PROTOCOLS:
        raise InputError(f"{protocol!r}: use one of {', '.join(PROTOCOLS)}", parameter="protocol")
    started = time.perf_counter()
    frames = list(scene.frames)
    photos = read_lom_photos(scene) if photos is None else photos
    images, references = photos.degraded, photos.references
    test_positions = [frames.index(frame) for frame in scene.test]
    fuse_views = [frame not in scene.test for frame in frames] if protocol == "holdout" else None
    if fuse_views is not None and not any(fuse_views):
        raise InputError(f"{scene.root}: the holdout protocol needs views besides the test frames")
    built = build_scene(images, frames, model, preset, geometry, None, max_views, scene.mode, None,
                        required_views=test_positions, fuse_views=fuse_views)
    cameras = built.geometry.cameras
    rendered = render_views(built.gaussians, cameras[[cameras.names.index(f) for f in scene.test]], preset.sh_degree,
                            fill=preset.fill_unobserved)
    renders = rendered.images
    inputs = images[test_positions]
    baseline_images = auto_gamma(inputs) if with_baseline else None
    used = [frames[i] for i in built.selected] if built.geometry.source == "network" else list(cameras.names)
    pose = _pose_accuracy(scene, used, cameras[[cameras.names.index(f) for f in used]].extrinsics.double())
    return SceneEvaluation(
        scene.name, protocol, len(built.selected), list(scene.test), meter.measure(renders, references),
        meter.measure(baseline_images, references) if with_baseline else [], time.perf_counter() - started, inputs,
        renders, baseline_images,
        references, pose, built.geometry.summary(), {"kept": len(built.gaussians), "budget": built.budget},
        rendered.summary(),
    )
