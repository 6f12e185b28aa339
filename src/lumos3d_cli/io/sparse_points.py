"""A sparse point cloud with its observations: which view sees which point at which pixel."""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from lumos3d_cli.io.cameras import Cameras


@dataclass
class SparsePoints:
    """P points seen in O observations.

    xyz [P, 3] float64 world coordinates; rgb [P, 3] uint8; error [P] float64 mean reprojection
    error in pixels; view [O] int64 index of the observing view (into the cameras or photos the
    points come with: for structure-from-motion all photos given to it, not only the registered
    ones); point [O] int64 index into xyz; pixel [O, 2] float64 (u, v) in pixels of the views,
    origin at the top-left pixel corner.
    """

    xyz: torch.Tensor
    rgb: torch.Tensor
    error: torch.Tensor
    view: torch.Tensor
    point: torch.Tensor
    pixel: torch.Tensor

    def __post_init__(self) -> None:
        count, observations = self.xyz.shape[0], self.view.shape[0]
        expected = {"xyz": (count, 3), "rgb": (count, 3), "error": (count,),
                    "view": (observations,), "point": (observations,), "pixel": (observations, 2)}
        for name, shape in expected.items():
            if tuple(getattr(self, name).shape) != shape:
                raise ValueError(f"sparse points: {name} has shape {tuple(getattr(self, name).shape)}, expected {shape}")

    def __len__(self) -> int:
        return self.xyz.shape[0]

    @staticmethod
    def empty() -> SparsePoints:
        return SparsePoints(
            torch.zeros(0, 3, dtype=torch.float64), torch.zeros(0, 3, dtype=torch.uint8),
            torch.zeros(0, dtype=torch.float64), torch.zeros(0, dtype=torch.int64),
            torch.zeros(0, dtype=torch.int64), torch.zeros(0, 2, dtype=torch.float64),
        )

    def reprojected(self, cameras: Cameras) -> tuple[SparsePoints, float]:
        """The points with `error` [P] measured against `cameras` (indexed by `view`): each point's
        mean distance in pixels between where the cameras project it and where it was observed, and
        the mean over all observations (COLMAP's mean reprojection error; nan without any)."""
        if len(self.view) == 0:
            return self, float("nan")
        extrinsics, intrinsics = cameras.extrinsics.double()[self.view], cameras.intrinsics.double()[self.view]
        camera = (extrinsics[:, :, :3] @ self.xyz[self.point][:, :, None])[..., 0] + extrinsics[:, :, 3]
        # a point at or behind a camera does not reproject: a huge, finite error (summary.json is JSON)
        depth = camera[:, 2:].clamp_min(1e-9)
        projected = (intrinsics[:, :2, :2] @ (camera[:, :2] / depth)[:, :, None])[..., 0] + intrinsics[:, :2, 2]
        distance = (projected - self.pixel).norm(dim=1)
        sums = torch.zeros(len(self), dtype=torch.float64).index_add_(0, self.point, distance)
        counts = torch.bincount(self.point, minlength=len(self)).clamp_min(1).double()
        return replace(self, error=sums / counts), float(distance.mean())
