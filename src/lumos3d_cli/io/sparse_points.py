"""A sparse point cloud with its observations: which view sees which point at which pixel."""

from __future__ import annotations

from dataclasses import dataclass

import torch


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

