"""The slow twin of the rasterizer: the same forward in dense pure PyTorch, differentiated by
autograd. Kept for tests (gradient and parity checks) and for tiny inputs; it holds
[pixels x Gaussians] tensors, so keep both small."""

from __future__ import annotations

import torch

from lumos3d_cli.io.gaussians import SH_C0
from lumos3d_cli.render.constants import (
    ALPHA_THRESHOLD,
    FOV_MARGIN,
    GAUSSIAN_EXTEND,
    MAX_ALPHA,
    MAX_RADIUS,
    MIN_COMPENSATION,
    SH_C1,
    SH_C2,
    SH_C3,
    SH_C4,
    TRANSMITTANCE_THRESHOLD,
)
from lumos3d_cli.render.settings import RasterSettings
from lumos3d_cli.rotations import quaternion_to_matrix


def sh_basis_reference(degree: int, directions: torch.Tensor) -> torch.Tensor:
    """[N, 3] unit directions -> [N, (degree+1)^2] basis values (3DGS order)."""
    x, y, z = directions.unbind(-1)
    values = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        values += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        values += [
            SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * zz - xx - yy), SH_C2[3] * x * z, SH_C2[4] * (xx - yy),
        ]
    if degree >= 3:
        values += [
            SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z, SH_C3[2] * y * (4 * zz - xx - yy),
            SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3 * yy),
        ]
    if degree >= 4:
        values += [
            SH_C4[0] * x * y * (xx - yy), SH_C4[1] * y * z * (3 * xx - yy), SH_C4[2] * x * y * (7 * zz - 1),
            SH_C4[3] * y * z * (7 * zz - 3), SH_C4[4] * (zz * (35 * zz - 30) + 3), SH_C4[5] * x * z * (7 * zz - 3),
            SH_C4[6] * (xx - yy) * (7 * zz - 1), SH_C4[7] * x * z * (xx - 3 * yy),
            SH_C4[8] * (xx * (xx - 3 * yy) - yy * (3 * xx - yy)),
        ]
    return torch.stack(values, dim=-1)


def covariance_reference(quats: torch.Tensor, scales: torch.Tensor) -> torch.Tensor:
    """World covariance R(q/|q|) diag(scales)^2 R^T [N,3,3] of quats [N,4] wxyz and scales [N,3];
    a (near-)zero quaternion counts as the identity (`rotations.unit_quaternions`)."""
    m = quaternion_to_matrix(quats) * scales[:, None, :]
    return m @ m.transpose(1, 2)


def world_to_camera_reference(means: torch.Tensor, covariances: torch.Tensor, viewmat: torch.Tensor):
    """Camera-space means [N,3] and covariances [N,3,3] under the [3,4] world->camera matrix."""
    rotation, translation = viewmat[:, :3].to(means.dtype), viewmat[:, 3].to(means.dtype)
    return means @ rotation.T + translation, rotation @ covariances @ rotation.T


def ewa_reference(means_c: torch.Tensor, cov_c: torch.Tensor, intrinsics, width: float, height: float):
    """Pinhole projection of camera-space means [N,3] (z > 0) and covariances [N,3,3]: means2d
    [N,2] in pixels and the undilated 2D covariance J cov_c J^T [N,2,2], J evaluated at the mean
    clamped to the field of view plus FOV_MARGIN."""
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    x, y, z = means_c.unbind(-1)
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    tx = z * torch.clamp(x / z, -(cx / fx + FOV_MARGIN * tan_x), (width - cx) / fx + FOV_MARGIN * tan_x)
    ty = z * torch.clamp(y / z, -(cy / fy + FOV_MARGIN * tan_y), (height - cy) / fy + FOV_MARGIN * tan_y)
    zero = torch.zeros_like(z)
    jacobian = torch.stack(
        [torch.stack([fx / z, zero, -fx * tx / z**2], -1), torch.stack([zero, fy / z, -fy * ty / z**2], -1)], dim=-2
    )
    means2d = torch.stack([fx * x / z + cx, fy * y / z + cy], dim=-1)
    return means2d, jacobian @ cov_c @ jacobian.transpose(1, 2)


def conic_reference(cov2d: torch.Tensor, opacities: torch.Tensor, eps2d: float, antialiased: bool):
    """Conics [N,3] = (A, B, C) of (cov2d + eps2d I)^-1 for cov2d [N,2,2], and the opacities [N]
    times the antialiasing compensation sqrt(det cov2d / det(cov2d + eps2d I)) when antialiased."""
    a0, b, c0 = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    a, c = a0 + eps2d, c0 + eps2d
    det = a * c - b * b
    if antialiased:
        opacities = opacities * torch.sqrt(torch.clamp_min((a0 * c0 - b * b) / det, MIN_COMPENSATION**2))
    return torch.stack([c / det, -b / det, a / det], dim=-1), opacities


def colours_reference(means: torch.Tensor, sh: torch.Tensor, campos: torch.Tensor, degree: int) -> torch.Tensor:
    """Colours [N,3] = max(0.5 + SH(sh [N,K,3], degree) at the unit direction from campos [3] to
    means [N,3], 0)."""
    directions = means - campos
    directions = directions / directions.norm(dim=-1, keepdim=True).clamp_min(1e-30)
    basis = sh_basis_reference(degree, directions)
    k = basis.shape[1]
    return torch.clamp_min((basis[:, :, None] * sh[:, :k, :]).sum(dim=1) + 0.5, 0.0)


def project_reference(means, quats, scales, opacities, sh, viewmat, intrinsics, settings: RasterSettings):
    """Per-Gaussian projection, the stages above in sequence. Returns means2d [N,2], conics [N,3],
    depths [N], opacities [N] (with compensation), colours [N,3] and radii [N,2] (int32, 0 =
    culled); the other outputs of culled Gaussians are finite but meaningless.

    The stages run in float64 whatever the inputs' dtype, as the kernel's per-Gaussian arithmetic
    does (its scalars are float64): in float32 the gradients of a Gaussian of std 1e12 were not
    finite where the kernel's were. The outputs take the inputs' dtype."""
    dtype = means.dtype
    means, quats, scales, opacities, sh = (tensor.to(torch.float64) for tensor in (means, quats, scales, opacities, sh))
    width, height = float(settings.width), float(settings.height)
    camera, cov_camera = world_to_camera_reference(means, covariance_reference(quats, scales), viewmat)
    x, y, z_true = camera.unbind(-1)
    in_depth_range = (z_true >= settings.near) & (z_true <= settings.far)
    z = torch.where(in_depth_range, z_true, torch.ones_like(z_true))  # culled ones stay finite
    means2d, cov2d = ewa_reference(torch.stack([x, y, z], dim=-1), cov_camera, intrinsics, width, height)
    conics, opacity = conic_reference(cov2d, opacities, settings.eps2d, settings.antialiased)

    with torch.no_grad():
        a, c = cov2d[:, 0, 0] + settings.eps2d, cov2d[:, 1, 1] + settings.eps2d
        det = a * c - cov2d[:, 0, 1] ** 2
        extend = torch.sqrt(2 * torch.log(opacity.clamp_min(ALPHA_THRESHOLD) / ALPHA_THRESHOLD)).clamp_max(GAUSSIAN_EXTEND)
        rx = torch.ceil(extend * torch.sqrt(a.clamp_min(0)))
        ry = torch.ceil(extend * torch.sqrt(c.clamp_min(0)))
        u, v = means2d.unbind(-1)
        valid = (
            in_depth_range & (det > 0) & (opacity >= ALPHA_THRESHOLD) & ~((rx <= 0) & (ry <= 0))
            & (u + rx > 0) & (u - rx < width) & (v + ry > 0) & (v - ry < height)
        )
        radii = torch.where(valid[:, None], torch.stack([rx, ry], -1).clamp_max(MAX_RADIUS),
                            torch.zeros_like(means2d)).to(torch.int32)

    rotation, translation = viewmat[:, :3].to(means.dtype), viewmat[:, 3].to(means.dtype)
    colours = colours_reference(means, sh, -rotation.T @ translation, settings.sh_degree)
    return (*(tensor.to(dtype) for tensor in (means2d, conics, z, opacity, colours)), radii)


def _composite_reference(means, quats, scales, opacities, sh, viewmat, intrinsics, settings: RasterSettings):
    """Dense front-to-back compositing of one camera: (colour [H,W,3], alpha [H,W], depth [H,W],
    radii [N,2], weights [H*W, M] = alpha x transmittance of every pixel and drawn Gaussian,
    order [M] the indices of those Gaussians, nearest first)."""
    means2d, conics, depths, opacity, colours, radii = project_reference(
        means, quats, scales, opacities, sh, viewmat, intrinsics, settings
    )
    dtype = means.dtype
    height, width = settings.height, settings.width
    keep = (radii > 0).any(dim=-1)
    index = torch.nonzero(keep).squeeze(1)
    order = index[torch.argsort(depths.detach()[index], stable=True)]
    rows = torch.arange(height, dtype=dtype) + 0.5
    cols = torch.arange(width, dtype=dtype) + 0.5
    py, px = torch.meshgrid(rows, cols, indexing="ij")
    px, py = px.reshape(-1, 1), py.reshape(-1, 1)
    dx = means2d[order, 0][None, :] - px
    dy = means2d[order, 1][None, :] - py
    ca, cb, cc = conics[order].unbind(-1)
    sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
    alpha = torch.clamp_max(opacity[order] * torch.exp(-sigma), MAX_ALPHA)
    skipped = (sigma < 0) | (alpha < ALPHA_THRESHOLD)
    alpha = torch.where(skipped, torch.zeros_like(alpha), alpha)
    with torch.no_grad():
        contributes = torch.cumprod(1 - alpha, dim=1) > TRANSMITTANCE_THRESHOLD
    alpha = alpha * contributes
    transmittance = torch.cumprod(1 - alpha, dim=1)
    before = torch.cat([torch.ones_like(transmittance[:, :1]), transmittance[:, :-1]], dim=1)
    weights = alpha * before
    colour = (weights @ colours[order]).reshape(height, width, 3)
    depth = (weights @ depths[order]).reshape(height, width)
    final = transmittance[:, -1] if order.numel() else torch.ones(height * width, dtype=dtype)
    return colour, (1 - final).reshape(height, width), depth, radii, weights, order


def rasterize_reference(means, quats, scales, opacities, sh, viewmat, intrinsics, settings: RasterSettings):
    """Same outputs as RasterizeGaussians: colour [H,W,3], alpha [H,W], depth [H,W] (sum of w z),
    radii [N,2]."""
    return _composite_reference(means, quats, scales, opacities, sh, viewmat, intrinsics, settings)[:4]


def rasterize_with_weights_reference(means, quats, scales, opacities, sh, viewmat, intrinsics, settings: RasterSettings):
    """Same outputs as `rasterizer.rasterize_with_weights` (no gradients): colour, alpha, depth,
    radii and weights [N] = each Gaussian's sum over pixels of alpha x transmittance."""
    with torch.no_grad():
        colour, alpha, depth, radii, weights, order = _composite_reference(
            means, quats, scales, opacities, sh, viewmat, intrinsics, settings
        )
        per_gaussian = torch.zeros(means.shape[0], dtype=means.dtype).index_add(0, order, weights.sum(dim=0))
    return colour, alpha, depth, radii, per_gaussian
