"""What a rasterization call needs besides the Gaussians and the camera."""

from __future__ import annotations

import math
from dataclasses import dataclass

from lumos3d_cli.render.constants import EPS2D, FAR_PLANE, NEAR_PLANE


@dataclass(frozen=True)
class RasterSettings:
    """Image size in pixels, SH degree used for colour, clipping planes (camera-space z),
    the 2D dilation eps2d and whether opacities get the antialiasing compensation
    sqrt(det(cov2d) / det(cov2d + eps2d I)) (Mip-Splatting's 2D filter)."""

    width: int
    height: int
    sh_degree: int = 0
    near: float = NEAR_PLANE
    far: float = FAR_PLANE
    eps2d: float = EPS2D
    antialiased: bool = False

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"image size {self.width}x{self.height}: width and height must be at least 1")
        if not 0 < self.near < self.far:
            raise ValueError(f"clipping planes near={self.near}, far={self.far}: need 0 < near < far")
        if not 0 <= self.eps2d < math.inf:  # NaN rendered black, Inf NaN images in the reference
            raise ValueError(f"eps2d={self.eps2d} must be finite and >= 0")
