"""Whether any camera can draw a scene at all: the rasterizer's clipping planes are absolute
(render.constants NEAR_PLANE and FAR_PLANE, as gsplat's), so a scene in extreme units (poses in
kilometres given as micro-units, a .ply scaled by 1e-6 or 1e12) lies wholly before the near plane
or beyond the far one, and every view of it would be black."""

from __future__ import annotations

import math

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.render.constants import FAR_PLANE, NEAR_PLANE

_SAMPLED_MEANS = 20_000  # enough to find a drawable Gaussian; the test is over every camera
_CAMERAS_AT_ONCE = 64  # [64, 20,000] depths at a time: an orbit of 100,000 frames stays small


def require_drawable(means: torch.Tensor, cameras: Cameras, where: str | None = None, parameter: str | None = None) -> None:
    """means [N, 3] (N >= 1), cameras (V >= 1): InputError (naming `where`, the file, when given)
    when no camera has any of the means (every k-th, at most _SAMPLED_MEANS) between its near and
    far planes. Camera depths only, a chunk of cameras at a time, stopping at the first that
    draws something."""
    sampled = means.detach()[:: max(1, math.ceil(len(means) / _SAMPLED_MEANS))].to("cpu", torch.float64)
    extrinsics = cameras.extrinsics.detach().to("cpu", torch.float64)
    ahead = []  # some positive depths to say where the scene lies: at most _SAMPLED_MEANS kept
    kept = 0
    for first in range(0, len(extrinsics), _CAMERAS_AT_ONCE):
        chunk = extrinsics[first: first + _CAMERAS_AT_ONCE]
        depth = chunk[:, 2, :3] @ sampled.T + chunk[:, 2, 3:]  # [C, P] camera-space z
        if bool(((depth >= NEAR_PLANE) & (depth <= FAR_PLANE)).any()):
            return
        if kept < _SAMPLED_MEANS:
            positive = depth[depth > 0][: _SAMPLED_MEANS - kept]
            ahead.append(positive)
            kept += len(positive)
    ahead = torch.cat(ahead)
    prefix = f"{where}: " if where else ""
    if not len(ahead):  # a question of orientation (or of cameras inside the scene), not of units
        raise InputError(f"{prefix}no camera sees the scene: it lies behind every camera (or at its centre); check that "
                         "the cameras face the scene (world-to-camera, OpenCV axes: +z forward; docs/formats.md)",
                         parameter=parameter)
    raise InputError(f"{prefix}no camera sees the scene: it lies {float(ahead.median()):.3g} units in front of the "
                     f"cameras, outside the renderer's range of {NEAR_PLANE:g} to {FAR_PLANE:g} units; give the scene and "
                     "its cameras in units that put it about 0.1 to 1e8 units away (metres, say)", parameter=parameter)
