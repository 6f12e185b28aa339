"""A glTF binary preview of a restored scene: Gaussian centres as coloured points and camera
frustums as lines (trimesh), openable in any glTF viewer.

glTF is y-up; our world frame is the first camera's OpenCV frame (y down, z forward), so
positions are written with y and z negated to stand the scene upright in viewers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from lumos3d_cli.io.atomic import write_bytes_atomic
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.colour import srgb_to_linear
from lumos3d_cli.io.gaussians import Gaussians, sh_dc_to_rgb

_TO_GLTF = np.array([1.0, -1.0, -1.0])
_MIN_OPACITY = 0.05


def frustum_segments(cameras: Cameras, depth: float) -> np.ndarray:
    """[V * 8, 2, 3] line segments: centre to the four image corners at `depth`, and the image
    rectangle there."""
    segments = []
    for index in range(len(cameras)):
        width, height = cameras.sizes[index]
        k_inverse = torch.linalg.inv(cameras.intrinsics[index].double())
        rotation = cameras.extrinsics[index, :, :3].double()
        centre = cameras.centers()[index].double()
        pixels = torch.tensor([[0, 0, 1], [width, 0, 1], [width, height, 1], [0, height, 1]], dtype=torch.float64)
        corners = centre + depth * (pixels @ k_inverse.T) @ rotation  # R^T applied to each row
        for a in range(4):
            segments.append([centre.numpy(), corners[a].numpy()])
            segments.append([corners[a].numpy(), corners[(a + 1) % 4].numpy()])
    return np.asarray(segments).reshape(-1, 2, 3)


def write_preview_glb(path: Path | str, gaussians: Gaussians, cameras: Cameras, max_points: int = 300_000) -> None:
    """Write the preview atomically; points below 5 % opacity are left out, at most
    `max_points` (evenly strided) are kept."""
    # imported here: trimesh (with scipy) is half a second of every command's start-up otherwise;
    # a restore loads it in the background while structure-from-motion runs (pipeline.module_prefetch)
    import trimesh

    g = gaussians.detach().to(device="cpu", dtype=torch.float32)
    solid = g.opacities >= _MIN_OPACITY
    means = g.means[solid].numpy().astype(np.float64)
    colours = sh_dc_to_rgb(g.sh[solid][:, 0, :]).clamp(0, 1).numpy()
    if len(means) > max_points:
        keep = np.linspace(0, len(means) - 1, max_points).round().astype(np.int64)
        means, colours = means[keep], colours[keep]
    # glTF's vertex colours are linear (its viewers encode them for display): 8-bit linear codes
    linear = srgb_to_linear(colours)
    rgba = np.concatenate([np.round(linear * 255), np.full((len(colours), 1), 255)], axis=1).astype(np.uint8)
    geometry = []
    if len(means):
        geometry.append(trimesh.PointCloud(means * _TO_GLTF, colors=rgba))
    centres = cameras.centers().double().numpy()
    spread = np.linalg.norm(centres - centres.mean(axis=0), axis=1).max() if len(centres) > 1 else 0.0
    extent = float(np.median(np.linalg.norm(means - centres[0], axis=1))) if len(means) else 1.0
    depth = max(spread * 0.3, extent * 0.08, 1e-3)
    geometry.append(trimesh.load_path(frustum_segments(cameras, depth) * _TO_GLTF))
    write_bytes_atomic(path, trimesh.Scene(geometry).export(file_type="glb"))
