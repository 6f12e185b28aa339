"""Similarity transforms (scale, rotation, translation) between two world frames, fitted by
Umeyama's least squares, and cameras carried from one frame into the other.

Used to place cameras that structure-from-motion did not register: the network's cameras of the
registered views are fitted to the SfM cameras, and the same transform carries the others over.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.cameras import Cameras

# Relative size of the second singular value of centred points below which they lie on a line
# (or on one point) and a rotation about that line cannot be determined.
_COLLINEAR = 1e-9


@dataclass(frozen=True)
class Similarity:
    """x -> scale * rotation @ x + translation; rotation [3, 3], translation [3] (float64)."""

    scale: float
    rotation: torch.Tensor
    translation: torch.Tensor

    def apply(self, points: torch.Tensor) -> torch.Tensor:
        """points [..., 3] -> [..., 3]."""
        rotation, translation = self.rotation.to(points), self.translation.to(points)
        return self.scale * points @ rotation.T + translation

    def inverse(self) -> Similarity:
        rotation = self.rotation.T
        return Similarity(1.0 / self.scale, rotation, -(rotation @ self.translation) / self.scale)


def fit_similarity(source: torch.Tensor, target: torch.Tensor) -> Similarity:
    """The similarity that maps source points [N, 3] onto target points [N, 3] in the least-squares
    sense (Umeyama 1991: SVD of the cross-covariance, reflection excluded).

    InputError for fewer than 3 pairs, non-finite values, or source or target points that all lie
    on one line (the rotation about it is then undetermined).
    """
    if source.shape != target.shape or source.dim() != 2 or source.shape[1] != 3:
        raise InputError(f"similarity needs two point sets [N, 3] of one shape, "
                         f"got {tuple(source.shape)} and {tuple(target.shape)}")
    if source.shape[0] < 3:
        raise InputError(f"a similarity needs at least 3 point pairs, got {source.shape[0]}")
    require_finite("similarity source points", source)
    require_finite("similarity target points", target)
    source, target = source.double(), target.double()
    source_mean, target_mean = source.mean(0), target.mean(0)
    source_centred, target_centred = source - source_mean, target - target_mean
    for name, centred in (("source", source_centred), ("target", target_centred)):
        spread = torch.linalg.svdvals(centred)
        if spread[1] <= _COLLINEAR * max(float(spread[0]), 1e-300):
            raise InputError(f"similarity: the {name} points lie on one line or point; the rotation is undetermined")
    covariance = target_centred.T @ source_centred / source.shape[0]
    u, singular, vh = torch.linalg.svd(covariance)
    sign = torch.ones(3, dtype=torch.float64)
    if torch.linalg.det(u) * torch.linalg.det(vh) < 0:
        sign[2] = -1.0
    rotation = u @ torch.diag(sign) @ vh
    variance = source_centred.square().sum(1).mean()
    scale = float((singular * sign).sum() / variance)
    return Similarity(scale, rotation, target_mean - scale * rotation @ source_mean)


def moved_to_origin(cameras: Cameras, origin: torch.Tensor) -> Cameras:
    """The cameras, in float64, in the world frame moved so that `origin` [3] (a point of theirs)
    is its origin: exact, where float32 loses a frame millions of units out."""
    origin = origin.to(torch.float64)
    return transform_cameras(cameras.to(dtype=torch.float64), Similarity(1.0, torch.eye(3, dtype=torch.float64), -origin))


def transform_cameras(cameras: Cameras, similarity: Similarity) -> Cameras:
    """The same cameras in the frame that `similarity` maps their world into. Camera-space
    lengths scale with the world: R' = R S^T, t' = s t - R S^T T for world->camera [R | t]."""
    rotation = similarity.rotation.to(cameras.extrinsics)
    new_rotation = cameras.extrinsics[:, :, :3] @ rotation.T
    translation = similarity.translation.to(cameras.extrinsics)
    new_translation = similarity.scale * cameras.extrinsics[:, :, 3] - new_rotation @ translation
    extrinsics = torch.cat([new_rotation, new_translation[:, :, None]], dim=2)
    return Cameras(extrinsics, cameras.intrinsics.clone(), list(cameras.sizes), list(cameras.names))


def _anchor_points(cameras: Cameras) -> torch.Tensor:
    """[3V, 3]: each camera's centre and the points one spread ahead along its optical axis and
    its x axis, the spread being the RMS distance of the centres from their mean (so the anchors
    of two frames related by a similarity are related by it too, and two cameras are enough)."""
    centres = cameras.centers().double()
    spread = (centres - centres.mean(0)).square().sum(1).mean().sqrt().clamp_min(1e-12)
    axes = cameras.extrinsics[:, :, :3].double()  # rows: camera x, y, z axes in world coordinates
    return torch.cat([centres, centres + spread * axes[:, 2], centres + spread * axes[:, 0]])


def fit_camera_similarity(source: Cameras, target: Cameras) -> Similarity:
    """The similarity that carries `source` cameras onto `target` cameras of the same views
    (matched by position), fitted on their centres and orientations: it is determined by two
    cameras with distinct centres, also when the centres lie on a line."""
    if len(source) != len(target):
        raise InputError(f"camera similarity needs the same views in both frames, got {len(source)} and {len(target)}")
    if len(source) < 2:
        raise InputError(f"a camera similarity needs at least 2 cameras, got {len(source)}")
    return fit_similarity(_anchor_points(source), _anchor_points(target))


def fill_unregistered_views(registered_cameras: Cameras, registered: torch.Tensor, other_cameras: Cameras) -> Cameras:
    """All V cameras in the registered frame: registered [V] bool marks the views that
    `registered_cameras` (in view order) holds; the rest come from `other_cameras` (all V views,
    e.g. the network's), carried over by the similarity fitted on the registered views. A carried
    view keeps its own intrinsics unless the registered views share one camera of its image size,
    which it then takes (one physical camera)."""
    if len(other_cameras) != registered.shape[0] or int(registered.sum()) != len(registered_cameras):
        raise InputError(f"{len(other_cameras)} cameras, {registered.shape[0]} views and {int(registered.sum())} "
                         f"registered flags for {len(registered_cameras)} registered cameras do not match")
    indices = torch.nonzero(registered).flatten().tolist()
    similarity = fit_camera_similarity(other_cameras[indices], registered_cameras)
    carried = transform_cameras(other_cameras, similarity)
    extrinsics = carried.extrinsics.to(registered_cameras.extrinsics.dtype).clone()
    intrinsics = carried.intrinsics.to(registered_cameras.intrinsics.dtype).clone()
    extrinsics[indices] = registered_cameras.extrinsics
    intrinsics[indices] = registered_cameras.intrinsics
    shared = registered_cameras.intrinsics[0]
    one_camera = torch.equal(registered_cameras.intrinsics, shared.expand_as(registered_cameras.intrinsics))
    if len(set(registered_cameras.sizes)) == 1 and one_camera:
        for view in range(len(other_cameras)):
            if not registered[view] and other_cameras.sizes[view] == registered_cameras.sizes[0]:
                intrinsics[view] = shared
    sizes = list(other_cameras.sizes)
    for row, view in enumerate(indices):
        sizes[view] = registered_cameras.sizes[row]
    return Cameras(extrinsics, intrinsics, sizes, list(other_cameras.names))
