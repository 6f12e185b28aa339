"""The one camera type and its axis conventions.

Extrinsics are world->camera [R | t] with OpenCV camera axes (x right, y down, z forward).
Intrinsics are in pixels of the image the camera describes, with the origin at the top-left
*corner* of the top-left pixel (pixel centres at +0.5, as COLMAP and gsplat): the principal
point of a centred camera is (W/2, H/2), and resizing scales fx, fy, cx, cy by the same factors.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import torch

from lumos3d_cli.errors import InputError, NonFiniteError, listed


# Flipping y and z turns OpenGL/nerfstudio camera axes (x right, y up, z back) into OpenCV's
# (x right, y down, z forward) and back: the map is its own inverse.
_GL_CV_FLIP = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))


def opengl_to_opencv(camera_to_world: torch.Tensor) -> torch.Tensor:
    """[..., 4, 4] camera->world with OpenGL axes <-> OpenCV axes (an involution)."""
    return camera_to_world @ _GL_CV_FLIP.to(camera_to_world)


opencv_to_opengl = opengl_to_opencv


def make_intrinsics(fx, fy, cx, cy) -> torch.Tensor:
    """[V] tensors (or floats) -> [V, 3, 3] pinhole matrices."""
    fx, fy, cx, cy = (torch.as_tensor(v, dtype=torch.float64).reshape(-1) for v in (fx, fy, cx, cy))
    k = torch.zeros(fx.shape[0], 3, 3, dtype=torch.float64)
    k[:, 0, 0], k[:, 1, 1], k[:, 0, 2], k[:, 1, 2], k[:, 2, 2] = fx, fy, cx, cy, 1.0
    return k


def invert_rigid(transform: torch.Tensor) -> torch.Tensor:
    """Invert [..., 3, 4] or [..., 4, 4] rigid transforms; returns [..., 4, 4]."""
    rotation, translation = transform[..., :3, :3], transform[..., :3, 3:]
    inverse = torch.zeros(transform.shape[:-2] + (4, 4), dtype=transform.dtype, device=transform.device)
    inverse[..., :3, :3] = rotation.transpose(-1, -2)
    inverse[..., :3, 3:] = -rotation.transpose(-1, -2) @ translation
    inverse[..., 3, 3] = 1.0
    return inverse


def to_homogeneous(transform: torch.Tensor) -> torch.Tensor:
    """[..., 3, 4] -> [..., 4, 4]."""
    bottom = torch.zeros(transform.shape[:-2] + (1, 4), dtype=transform.dtype, device=transform.device)
    bottom[..., 0, 3] = 1.0
    return torch.cat([transform[..., :3, :], bottom], dim=-2)


@dataclass
class Cameras:
    """V pinhole cameras.

    extrinsics [V, 3, 4] world->camera (OpenCV axes); intrinsics [V, 3, 3];
    sizes: (width, height) in pixels per camera; names: image file name per camera ('' if none).
    """

    extrinsics: torch.Tensor
    intrinsics: torch.Tensor
    sizes: list[tuple[int, int]]
    names: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        v = self.extrinsics.shape[0]
        if tuple(self.extrinsics.shape) != (v, 3, 4):
            raise ValueError(f"extrinsics have shape {tuple(self.extrinsics.shape)}, expected ({v}, 3, 4)")
        if tuple(self.intrinsics.shape) != (v, 3, 3):
            raise ValueError(f"intrinsics have shape {tuple(self.intrinsics.shape)}, expected ({v}, 3, 3)")
        self.sizes = [(int(w), int(h)) for w, h in self.sizes]
        if len(self.sizes) != v:
            raise ValueError(f"{len(self.sizes)} image sizes for {v} cameras")
        self.names = list(self.names) if self.names else [""] * v
        if len(self.names) != v:
            raise ValueError(f"{len(self.names)} names for {v} cameras")

    def __len__(self) -> int:
        return self.extrinsics.shape[0]

    def __getitem__(self, index: int | slice | Sequence[int] | torch.Tensor) -> Cameras:
        """A subset (always a Cameras, also for an int index)."""
        if isinstance(index, int):
            index = [index]
        positions = list(range(len(self)))[index] if isinstance(index, slice) else [int(i) for i in index]
        return Cameras(
            self.extrinsics[positions], self.intrinsics[positions],
            [self.sizes[i] for i in positions], [self.names[i] for i in positions],
        )

    @staticmethod
    def concatenate(parts: Sequence[Cameras]) -> Cameras:
        """The cameras of `parts` in order, as one Cameras (extrinsics in float64 when the parts'
        dtypes differ)."""
        if not parts:
            raise ValueError("no cameras to concatenate")
        dtype = parts[0].extrinsics.dtype if len({p.extrinsics.dtype for p in parts}) == 1 else torch.float64
        return Cameras(
            torch.cat([p.extrinsics.to(dtype) for p in parts]), torch.cat([p.intrinsics.to(dtype) for p in parts]),
            [size for p in parts for size in p.sizes], [name for p in parts for name in p.names],
        )

    @staticmethod
    def from_camera_to_world(
        camera_to_world: torch.Tensor, intrinsics: torch.Tensor, sizes, names: Sequence[str] = ()
    ) -> Cameras:
        """Build from [V, 4, 4] (or [V, 3, 4]) camera->world matrices with OpenCV axes."""
        return Cameras(invert_rigid(camera_to_world)[:, :3, :], intrinsics, list(sizes), list(names))

    def camera_to_world(self) -> torch.Tensor:
        """[V, 4, 4] camera->world (OpenCV axes)."""
        return invert_rigid(self.extrinsics)

    def centers(self) -> torch.Tensor:
        """[V, 3] camera centres in world coordinates."""
        rotation, translation = self.extrinsics[:, :, :3], self.extrinsics[:, :, 3:]
        return (-rotation.transpose(1, 2) @ translation)[..., 0]

    def rescaled(self, width: int, height: int) -> Cameras:
        """The same cameras for images resized to width x height."""
        return self.rescaled_to([(width, height)] * len(self))

    def rescaled_to(self, sizes: Sequence[tuple[int, int]]) -> Cameras:
        """The same cameras for images resized to `sizes` (width, height), one per camera. A
        change of aspect ratio scales fx, cx and fy, cy by different factors: the camera of a
        stretched image stays exact."""
        if len(sizes) != len(self):
            raise ValueError(f"{len(sizes)} image sizes for {len(self)} cameras")
        intrinsics = self.intrinsics.clone()
        for i, ((w, h), (width, height)) in enumerate(zip(self.sizes, sizes)):
            intrinsics[i, 0, :] *= width / w
            intrinsics[i, 1, :] *= height / h
        return Cameras(self.extrinsics.clone(), intrinsics, list(sizes), list(self.names))

    def relative_to(self, index: int = 0) -> Cameras:
        """Re-express in the frame of camera `index` (that camera gets identity extrinsics)."""
        reference_to_world = invert_rigid(self.extrinsics[index])
        extrinsics = to_homogeneous(self.extrinsics) @ reference_to_world
        return Cameras(extrinsics[:, :3, :], self.intrinsics.clone(), list(self.sizes), list(self.names))

    def to(self, *args, **kwargs) -> Cameras:
        return Cameras(
            self.extrinsics.to(*args, **kwargs), self.intrinsics.to(*args, **kwargs), list(self.sizes), list(self.names)
        )

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World points [P, 3] -> pixel coordinates [V, P, 2] and camera-space depth [V, P]."""
        camera = self.extrinsics[:, None, :, :3] @ points[None, :, :, None] + self.extrinsics[:, None, :, 3:]
        camera = camera[..., 0]
        depth = camera[..., 2]
        pixels = (self.intrinsics[:, None, :2, :2] @ (camera[..., :2] / depth[..., None])[..., None])[..., 0]
        return pixels + self.intrinsics[:, None, :2, 2], depth

    def require_valid(self, where: str = "cameras", remedy: str = "correct the file") -> None:
        """Finite values, proper rotations, positive focal lengths and image sizes; otherwise
        NonFiniteError, or InputError naming `where` and the view and ending in `remedy`."""
        for what, values in (("pose", self.extrinsics), ("intrinsics", self.intrinsics)):
            broken = ~torch.isfinite(values.detach()).flatten(1).all(dim=1)
            if bool(broken.any()):
                views = [self._view_name(int(index)) for index in broken.nonzero().flatten()]
                whose = f"the {what} of {views[0]} holds" if len(views) == 1 else f"the {what} of {listed(views, 3)} hold"
                raise NonFiniteError(f"{where}: {whose} NaN or Inf; {remedy}")
        rotation = self.extrinsics[:, :, :3].double()
        identity = torch.eye(3, dtype=torch.float64).expand_as(rotation)
        not_rotations = ((rotation @ rotation.transpose(1, 2) - identity).abs().amax(dim=(1, 2)) > 1e-4) | (
            torch.linalg.det(rotation) < 0)
        if not_rotations.any():
            raise InputError(f"{where}: the pose of {self._view_name(int(not_rotations.nonzero()[0]))} holds a matrix "
                             f"that is not a rotation (scaled, sheared, mirrored or singular); {remedy}")
        bad_focal = (self.intrinsics[:, 0, 0] <= 0) | (self.intrinsics[:, 1, 1] <= 0)
        if bad_focal.any():
            raise InputError(f"{where}: the focal length of {self._view_name(int(bad_focal.nonzero()[0]))} is not "
                             f"positive; {remedy}")
        for index, (width, height) in enumerate(self.sizes):
            if width < 1 or height < 1:
                raise InputError(f"{where}: the image size of {self._view_name(index)} is {width}x{height} pixels; "
                                 f"{remedy}")

    def _view_name(self, index: int) -> str:
        return f"view {index} ({self.names[index]})" if self.names and self.names[index] else f"view {index}"
