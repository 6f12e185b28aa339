"""The in-memory Gaussian scene: activated parameters, one row per Gaussian."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch

from lumos3d_cli.checks import require_finite

# The one home of both (the .ply/.splat files, colour conversions and the rasterizer import them).
SH_C0 = 0.28209479177387814  # Y_0^0; rgb = 0.5 + SH_C0 * f_dc
MAX_SH_DEGREE = 4  # highest SH degree read, written and rendered


def sh_coefficient_count(degree: int) -> int:
    """K = (degree + 1)^2 coefficients per colour channel."""
    return (degree + 1) ** 2


def sh_degree_from_count(count: int) -> int:
    """Inverse of `sh_coefficient_count`; ValueError when `count` is not a square."""
    degree = math.isqrt(count) - 1
    if degree < 0 or (degree + 1) ** 2 != count:
        raise ValueError(f"{count} SH coefficients per channel is not (degree + 1)^2")
    return degree


def rgb_to_sh_dc(rgb: torch.Tensor) -> torch.Tensor:
    """Colour in [0, 1] -> degree-0 SH coefficient (inverse of rgb = 0.5 + C0 * f_dc)."""
    return (rgb - 0.5) / SH_C0


def sh_dc_to_rgb(dc: torch.Tensor) -> torch.Tensor:
    """Degree-0 SH coefficients [..., 3] -> their colour [..., 3] (rgb = 0.5 + C0 * f_dc; not clamped)."""
    return 0.5 + SH_C0 * dc


@dataclass
class Gaussians:
    """A set of 3D Gaussians.

    means [N, 3]; quats [N, 4] wxyz (not necessarily normalised); scales [N, 3] standard
    deviations along the local axes (linear, > 0); opacities [N] in [0, 1]; sh [N, K, 3] with
    K = (degree + 1)^2, coefficient-major.
    """

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor
    sh: torch.Tensor

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        expected = {"means": (n, 3), "quats": (n, 4), "scales": (n, 3), "opacities": (n,)}
        for name, shape in expected.items():
            if tuple(getattr(self, name).shape) != shape:
                raise ValueError(f"Gaussians.{name} has shape {tuple(getattr(self, name).shape)}, expected {shape}")
        if self.sh.dim() != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3:
            raise ValueError(f"Gaussians.sh has shape {tuple(self.sh.shape)}, expected ({n}, K, 3)")
        if sh_degree_from_count(self.sh.shape[1]) > MAX_SH_DEGREE:
            raise ValueError(f"Gaussians.sh holds {self.sh.shape[1]} coefficients per channel (SH degree "
                             f"{sh_degree_from_count(self.sh.shape[1])}); degrees 0 to {MAX_SH_DEGREE} are supported")

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return sh_degree_from_count(self.sh.shape[1])

    def tensors(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def map(self, function) -> Gaussians:
        """Apply `function` to every tensor (e.g. `lambda t: t.to(device)`)."""
        return Gaussians(**{name: function(t) for name, t in self.tensors().items()})

    def select(self, index: torch.Tensor) -> Gaussians:
        """Rows picked by a boolean mask or integer index."""
        return self.map(lambda t: t[index])

    def detach(self) -> Gaussians:
        return self.map(torch.Tensor.detach)

    def with_sh_degree(self, degree: int) -> Gaussians:
        """The same Gaussians with the SH bands above `degree` dropped (unchanged at or above
        their own degree); sh [N, (degree + 1)^2, 3], contiguous."""
        if degree >= self.sh_degree:
            return self
        return Gaussians(self.means, self.quats, self.scales, self.opacities,
                         self.sh[:, : sh_coefficient_count(degree)].contiguous())

    def to(self, *args, **kwargs) -> Gaussians:
        return self.map(lambda t: t.to(*args, **kwargs))

    def require_finite(self, where: str = "Gaussians") -> None:
        """Raise NonFiniteError naming the first tensor that holds NaN or Inf."""
        for name, tensor in self.tensors().items():
            require_finite(f"{where}.{name}", tensor)

    def require_activated(self, where: str = "Gaussians") -> None:
        """ValueError unless the opacities lie in [0, 1] and the scales are not negative: the
        activated values these tensors hold (an opacity of 2 rendered, then saved as 1; a negative
        scale rendered as its size, then saved as 1e-30)."""
        for name, tensor, outside in (("opacities", self.opacities, (self.opacities < 0) | (self.opacities > 1)),
                                      ("scales", self.scales, self.scales < 0)):
            if bool(outside.any()):
                first = float(tensor.detach()[outside][0])
                raise ValueError(f"{where}.{name}: {int(outside.sum())} value(s) outside the activated range ({first:g}; "
                                 f"{'opacities lie in [0, 1]' if name == 'opacities' else 'scales are not negative'}): "
                                 "give activated values (sigmoid of the opacity logit, exp of the log-scale)")

    def require_float32_range(self, where: str = "Gaussians") -> None:
        """ValueError naming the first tensor with a value beyond float32's range (3.4e38): the
        files store float32, where such a value (finite in float64) became Inf."""
        limit = float(torch.finfo(torch.float32).max)
        for name, tensor in self.tensors().items():
            beyond = tensor.detach().abs() > limit
            if bool(beyond.any()):
                raise ValueError(f"{where}.{name}: {int(beyond.sum())} value(s) beyond float32's range "
                                 f"({float(tensor.detach()[beyond][0]):g}; at most {limit:.3g}): the file stores float32")

    @staticmethod
    def concatenate(parts: list[Gaussians]) -> Gaussians:
        first = parts[0]
        return Gaussians(**{name: torch.cat([getattr(p, name) for p in parts]) for name in first.tensors()})
