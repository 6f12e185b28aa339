"""Per-view camera corrections, differentiated through the CPU rasterizer.

The rasterizer does not differentiate its camera, but moving a camera is the same as moving the
scene the other way: correcting view v's world->camera map V by D = (exp(omega), tau) (applied
in camera space, V' = D V) renders exactly what V shows of the Gaussians moved by
W = V^-1 D V. Means and rotations are differentiable inputs of the rasterizer, so the
corrections get their gradients from its hand-written backward. View-dependent colour is taken
at the corrected camera centre and passed as a colour (degree 0), which keeps it exact too.
"""

from __future__ import annotations

import torch

from lumos3d_cli.io.gaussians import Gaussians, rgb_to_sh_dc
from lumos3d_cli.render.reference import colours_reference

# Below this angle (radians) the rotation's series are used: exact to float64 rounding there.
_SMALL_ANGLE = 1e-4


def _skew(vectors: torch.Tensor) -> torch.Tensor:
    """[..., 3] -> [..., 3, 3] cross-product matrices."""
    x, y, z = vectors.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(vectors.shape + (3,))


def axis_angle_to_matrix(omega: torch.Tensor) -> torch.Tensor:
    """[3] axis x angle -> [3, 3] rotation (Rodrigues), smooth through omega = 0."""
    theta2 = (omega * omega).sum()
    theta = torch.sqrt(theta2.clamp_min(_SMALL_ANGLE**2))
    small = theta2 < _SMALL_ANGLE**2
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / theta**2)
    k = _skew(omega)
    return torch.eye(3, dtype=omega.dtype, device=omega.device) + a * k + b * (k @ k)


def axis_angle_to_quaternion(omega: torch.Tensor) -> torch.Tensor:
    """[3] axis x angle -> [4] unit quaternion wxyz, smooth through omega = 0."""
    theta2 = (omega * omega).sum()
    theta = torch.sqrt(theta2.clamp_min(_SMALL_ANGLE**2))
    small = theta2 < _SMALL_ANGLE**2
    half_sinc = torch.where(small, 0.5 - theta2 / 48, torch.sin(theta / 2) / theta)
    w = torch.where(small, 1 - theta2 / 8, torch.cos(theta / 2))
    return torch.cat([w[None], half_sinc * omega])


def quaternion_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of wxyz quaternions a [..., 4] and b [..., 4] (rotation a after b)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], dim=-1)


class CameraCorrections:
    """Leaf tensors `rotations` [V, 3] (axis x angle, radians) and `translations` [V, 3] (world
    units), both in each camera's own frame, for the world->camera extrinsics [V, 3, 4]; the
    views marked in `pinned` [V] bool stay as given (their gradient is zeroed)."""

    def __init__(self, extrinsics: torch.Tensor, pinned: torch.Tensor):
        self.extrinsics = extrinsics.detach().double()
        views = extrinsics.shape[0]
        self.free = (~pinned).double()[:, None]
        self.rotations = torch.zeros(views, 3, dtype=torch.float64, device=extrinsics.device, requires_grad=True)
        self.translations = torch.zeros(views, 3, dtype=torch.float64, device=extrinsics.device, requires_grad=True)

    def _delta(self, view: int) -> tuple[torch.Tensor, torch.Tensor]:
        return self.rotations[view] * self.free[view], self.translations[view] * self.free[view]

    def corrected(self, view: int) -> torch.Tensor:
        """[3, 4] V' = D V of `view` (differentiable)."""
        omega, tau = self._delta(view)
        rotation = axis_angle_to_matrix(omega)
        base = self.extrinsics[view]
        return torch.cat([rotation @ base[:, :3], (rotation @ base[:, 3] + tau)[:, None]], dim=1)

    def corrected_extrinsics(self) -> torch.Tensor:
        """[V, 3, 4] every view's corrected world->camera map (detached)."""
        with torch.no_grad():
            return torch.stack([self.corrected(view) for view in range(self.extrinsics.shape[0])])

    def moved_gaussians(self, view: int, gaussians: Gaussians, sh_degree: int) -> Gaussians:
        """`gaussians` as the uncorrected camera of `view` must see them to show what the
        corrected camera sees: means and rotations under W = V^-1 D V, SH [N, 1, 3] holding the
        colour seen from the corrected centre (degree `sh_degree`; the DC alone when 0)."""
        omega, _ = self._delta(view)
        base = self.extrinsics[view]
        rotation_v, translation_v = base[:, :3], base[:, 3]
        corrected = self.corrected(view)
        # W = V^-1 D V: rotation R_v^T R_d R_v (the angle of D about the axis R_v^T omega).
        rotation_w = rotation_v.T @ axis_angle_to_matrix(omega) @ rotation_v
        translation_w = rotation_v.T @ (corrected[:, 3] - translation_v)
        dtype = gaussians.means.dtype
        means = gaussians.means @ rotation_w.T.to(dtype) + translation_w.to(dtype)
        quats = quaternion_multiply(axis_angle_to_quaternion(rotation_v.T @ omega).to(dtype), gaussians.quats)
        if sh_degree == 0:
            sh = gaussians.sh[:, :1]
        else:
            centre = -corrected[:, :3].T @ corrected[:, 3]
            colours = colours_reference(gaussians.means, gaussians.sh, centre.to(dtype), sh_degree)
            sh = rgb_to_sh_dc(colours)[:, None, :]
        return Gaussians(means, quats, gaussians.scales, gaussians.opacities, sh)
