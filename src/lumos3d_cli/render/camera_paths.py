"""Camera paths for fly-through renders: orbits derived from input cameras or scene bounds."""

from __future__ import annotations

import math

import torch

from lumos3d_cli.io.cameras import Cameras, make_intrinsics
from lumos3d_cli.io.gaussians import Gaussians

# Cameras whose viewing directions all lie within this angle of their mean are "forward-facing"
# (LLFF-like captures): they get a small circle around the mean pose instead of a full orbit.
_FORWARD_FACING_DEGREES = 50.0


def look_at(positions: torch.Tensor, target: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
    """[V, 3] positions -> [V, 3, 4] world->camera extrinsics (OpenCV axes: y points opposite
    to `up`, z towards `target`)."""
    forward = torch.nn.functional.normalize(target - positions, dim=-1)
    down = -up.expand_as(forward)
    right = torch.nn.functional.normalize(torch.cross(down, forward, dim=-1), dim=-1)
    down = torch.cross(forward, right, dim=-1)
    rotation = torch.stack([right, down, forward], dim=1)  # rows: camera axes in world coordinates
    translation = -(rotation @ positions[..., None])
    return torch.cat([rotation, translation], dim=-1)


def _perpendicular_basis(up: torch.Tensor, reference: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Two unit vectors spanning the plane perpendicular to `up`, the first towards `reference`."""
    first = reference - (reference @ up) * up
    if first.norm() < 1e-9:
        first = torch.tensor([1.0, 0.0, 0.0], dtype=up.dtype) - up[0] * up
    first = first / first.norm()
    return first, torch.cross(up, first, dim=0)


def axes_meeting_point(centres: torch.Tensor, forwards: torch.Tensor) -> torch.Tensor | None:
    """centres [V, 3] and unit forward directions [V, 3] of the cameras -> the least-squares point
    [3] nearest to all their optical axes, or None when the axes are nearly parallel."""
    eye = torch.eye(3, dtype=centres.dtype)
    projectors = eye - forwards[:, :, None] * forwards[:, None, :]
    system = projectors.sum(dim=0)
    if torch.linalg.cond(system) > 1e4:
        return None
    target = torch.linalg.solve(system, (projectors @ centres[:, :, None]).sum(dim=0))[:, 0]
    in_front = ((target - centres) * forwards).sum(dim=1) > 0
    return target if bool(in_front.all()) else None


def orbit_from_cameras(cameras: Cameras, frames: int, width: int, height: int, gaussians: Gaussians | None = None) -> Cameras:
    """A closed path through the space the input cameras cover.

    Cameras around an object (viewing directions spread by more than 50 degrees) give a full
    orbit at their mean distance and height around the point their optical axes meet.
    Forward-facing captures give a circle through the cameras' spread around their mean pose,
    looking at the scene centre.
    """
    cameras = cameras.to(torch.float64)
    rotation = cameras.extrinsics[:, :, :3]
    centres = cameras.centers()
    forwards = rotation[:, 2, :]
    up = torch.nn.functional.normalize(-rotation[:, 1, :].mean(dim=0), dim=0)
    mean_forward = torch.nn.functional.normalize(forwards.mean(dim=0), dim=0)
    spread = torch.rad2deg(torch.arccos((forwards @ mean_forward).clamp(-1, 1))).max()
    target = axes_meeting_point(centres, forwards)
    if target is None:
        target = scene_centre(gaussians) if gaussians is not None else centres.mean(dim=0) + mean_forward
    angles = torch.arange(frames, dtype=torch.float64) * (2 * math.pi / frames)
    offsets = centres - target
    if spread > _FORWARD_FACING_DEGREES:
        heights = offsets @ up
        radius = (offsets - heights[:, None] * up).norm(dim=1).mean()
        first, second = _perpendicular_basis(up, offsets[0])
        positions = target + heights.mean() * up + radius * (
            torch.cos(angles)[:, None] * first + torch.sin(angles)[:, None] * second
        )
    else:
        mean_centre = centres.mean(dim=0)
        right, _ = _perpendicular_basis(mean_forward, rotation[:, 0, :].mean(dim=0))
        down = torch.cross(mean_forward, right, dim=0)
        radius = max(float((centres - mean_centre).norm(dim=1).max()), 1e-3 * float(offsets.norm(dim=1).mean()))
        positions = mean_centre + radius * (torch.cos(angles)[:, None] * right + torch.sin(angles)[:, None] * down)
    extrinsics = look_at(positions, target, up)
    first_camera = cameras[0].rescaled(width, height)
    return Cameras(extrinsics, first_camera.intrinsics.expand(frames, 3, 3).clone(), [(width, height)] * frames)


def scene_centre(gaussians: Gaussians) -> torch.Tensor:
    """[3] float64: the median position of the Gaussians that are not nearly transparent (of all,
    when every one is)."""
    means = gaussians.means.detach().double()
    solid = gaussians.opacities.detach() > 0.1
    return (means[solid] if solid.any() else means).median(dim=0).values


def orbit_from_gaussians(gaussians: Gaussians, frames: int, width: int, height: int, fov_degrees: float = 50.0) -> Cameras:
    """A full orbit around the scene's centre, for scenes without cameras. World up is -y
    (OpenCV convention, as in scenes whose first camera defines the world frame)."""
    if len(gaussians) == 0:
        raise ValueError("cannot derive an orbit from an empty scene; pass cameras instead")
    centre = scene_centre(gaussians)
    distances = (gaussians.means.detach().double() - centre).norm(dim=1)
    # the 90th-percentile distance (kthvalue: torch.quantile refuses more than 2^24 values), and no
    # less than the Gaussians' own size: one Gaussian, or many at one point, is a scene too
    reach = distances.kthvalue(max(1, math.ceil(0.9 * len(distances)))).values
    size = 3 * gaussians.scales.detach().double().amax(dim=1).median()
    extent = float(torch.maximum(reach, size).clamp_min(1e-6))
    up = torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)
    angles = torch.arange(frames, dtype=torch.float64) * (2 * math.pi / frames)
    first, second = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64), torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    positions = centre + 0.5 * extent * up + 2.5 * extent * (
        torch.cos(angles)[:, None] * first + torch.sin(angles)[:, None] * second
    )
    focal = 0.5 * width / math.tan(math.radians(fov_degrees) / 2)
    intrinsics = make_intrinsics(focal, focal, width / 2, height / 2).expand(frames, 3, 3).clone()
    return Cameras(look_at(positions, centre, up), intrinsics, [(width, height)] * frames)
