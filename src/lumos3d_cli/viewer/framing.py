"""The viewer's coordinate frame: the scene centred and scaled to a fixed size, and its up.

Scenes come in arbitrary units (a first-camera frame at unit depth, COLMAP units, metres). The
browser stores splat covariances as float16, whose normal range starts at 6e-5: a splat of
standard deviation 2 mm in a 1-unit scene (4e-6) would lose its shape. Scaling every scene to
the same radius keeps covariances in range and the browser's near/far planes sensible."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.rotations import matrix_to_quaternion

VIEWER_RADIUS = 10.0  # viewer units covering 90 % of the Gaussians' distance from the centre
_RADIUS_QUANTILE = 0.9  # far stragglers (sky, floaters) must not shrink the scene to a dot
_QUANTILE_SAMPLE = 200_000  # torch.quantile's input limit is 16M; a sample is plenty for a radius


@dataclass(frozen=True)
class ViewerFrame:
    """x_viewer = (x_world - centre) * scale; up [3] is the world's up in viewer axes (unit)."""

    centre: torch.Tensor  # [3] float64
    scale: float
    up: np.ndarray  # [3] float64

    def points(self, xyz: torch.Tensor | np.ndarray) -> np.ndarray:
        """World points [P, 3] -> viewer points [P, 3] float32."""
        xyz = torch.as_tensor(np.asarray(xyz), dtype=torch.float64)
        return ((xyz - self.centre) * self.scale).float().numpy()

    def camera_poses(self, cameras: Cameras) -> tuple[np.ndarray, np.ndarray]:
        """Viser poses of OpenCV cameras: wxyz [V, 4] (camera->world rotation), positions [V, 3]."""
        camera_to_world = cameras.camera_to_world().double()
        wxyz = matrix_to_quaternion(camera_to_world[:, :3, :3]).numpy()
        return wxyz, self.points(camera_to_world[:, :3, 3])


def camera_up(cameras: Cameras) -> np.ndarray:
    """[3] the mean of the cameras' up directions (-y of OpenCV axes) in world coordinates."""
    # Row 1 of world->camera R is the camera's y axis in world coordinates.
    up = -cameras.extrinsics[:, 1, :3].double().mean(dim=0)
    norm = float(up.norm())
    return (up / norm).numpy() if norm > 1e-6 else np.array([0.0, -1.0, 0.0])


def frame_scene(gaussians: Gaussians, cameras: Cameras | None) -> ViewerFrame:
    """Centre on the Gaussians' median, scale their 90th-percentile radius, and no less than three
    times their median size (one Gaussian, or many at one point, is a scene too: framed as `render
    --orbit` frames it, not as a dot), to VIEWER_RADIUS; up from the cameras, or -y (the first
    camera's up, where the world frame is that camera's)."""
    up = camera_up(cameras) if cameras is not None and len(cameras) else np.array([0.0, -1.0, 0.0])
    if len(gaussians) == 0:
        centre = cameras.centers().double().mean(dim=0) if cameras is not None and len(cameras) else torch.zeros(3, dtype=torch.float64)
        return ViewerFrame(centre, 1.0, up)
    means = gaussians.means.detach().to("cpu", torch.float64)
    if len(means) > _QUANTILE_SAMPLE:
        means = means[torch.linspace(0, len(means) - 1, _QUANTILE_SAMPLE).long()]
    centre = means.median(dim=0).values
    size = 3 * float(gaussians.scales.detach().to("cpu", torch.float64).amax(dim=1).median())
    radius = max(float(torch.quantile((means - centre).norm(dim=-1), _RADIUS_QUANTILE)), size)
    return ViewerFrame(centre, VIEWER_RADIUS / radius if radius > 0 else 1.0, up)


def view_position_showing(points: np.ndarray, direction: np.ndarray, up: np.ndarray, fov: float,
                          fill: float = 0.8) -> np.ndarray:
    """[3] a viewpoint on the ray from the viewer origin along `direction` [3], looking at the
    origin with vertical field of view `fov` (radians), far enough that every point of `points`
    [P, 3] lies in front of it and within `fill` of the half field of view, vertically and
    horizontally (the window is assumed no narrower than it is tall). Starts at the length of
    `direction` and only moves back: a scene photographed from far away with a long lens puts its
    cameras at several scene radii, beside the line of sight of a view placed just behind them."""
    start = float(np.linalg.norm(direction))
    axis = direction / max(start, 1e-9)
    right = np.cross(-axis, up)
    right /= max(float(np.linalg.norm(right)), 1e-9)
    true_up = np.cross(right, -axis)
    # Moving back along the axis leaves a point's offsets across the line of sight unchanged and
    # adds to its depth (distance - point . axis): each point needs depth >= its larger offset over
    # tan(fill * fov / 2), and a little more than nothing when it lies on the axis.
    across = np.maximum(np.abs(points @ right), np.abs(points @ true_up))
    needed = points @ axis + np.maximum(across / math.tan(fill * fov / 2), 1e-6)
    return max(start, float(needed.max(initial=-np.inf))) * axis
