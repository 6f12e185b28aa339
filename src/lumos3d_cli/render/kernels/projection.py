"""Per-Gaussian EWA projection, forward, parallel over Gaussians (backward: projection_backward.py).

Everything per Gaussian is computed in float64 whatever the storage dtype, which keeps
far-away scenes and huge or tiny scales well conditioned. Array layout:
means [N,3], quats [N,4] wxyz, scales [N,3], opacities [N], sh [N,K,3];
viewmat [3,4] world->camera; outputs means2d [N,2], conics [N,3] (A, B, C of the inverse 2D
covariance), depths [N], opacities_eff [N], colours [N,3], radii [N,2] (0 = culled).

The per-Gaussian steps are small functions shared with the backward pass, which recomputes
them instead of storing [N]-sized intermediates.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from lumos3d_cli.render.constants import (
    ALPHA_THRESHOLD,
    DEGENERATE_QUATERNION_NORM,
    FOV_MARGIN,
    GAUSSIAN_EXTEND,
    MIN_COMPENSATION,
)
from lumos3d_cli.render.kernels.sh import sh_basis

CHUNK = 1024  # Gaussians per parallel work item; scratch arrays are allocated once per chunk


@njit(cache=True)
def camera_centre(viewmat):
    """[3] = -R^T t of a [3,4] world->camera matrix."""
    centre = np.empty(3)
    for r in range(3):
        centre[r] = -(viewmat[0, r] * viewmat[0, 3] + viewmat[1, r] * viewmat[1, 3] + viewmat[2, r] * viewmat[2, 3])
    return centre


@njit(cache=True)
def unit_quaternion(quats, i, out):
    """out[:4] = normalised wxyz of quats[i]; returns the norm (0 for a degenerate quaternion,
    which is then treated as identity)."""
    norm = 0.0
    for r in range(4):
        norm += float(quats[i, r]) ** 2
    norm = math.sqrt(norm)
    if norm < DEGENERATE_QUATERNION_NORM:
        out[0], out[1], out[2], out[3] = 1.0, 0.0, 0.0, 0.0
        return 0.0
    for r in range(4):
        out[r] = float(quats[i, r]) / norm
    return norm


@njit(cache=True)
def rotation(q, out):
    """out[3,3] = rotation matrix of the unit quaternion q[4] (wxyz)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - w * z)
    out[0, 2] = 2.0 * (x * z + w * y)
    out[1, 0] = 2.0 * (x * y + w * z)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - w * x)
    out[2, 0] = 2.0 * (x * z - w * y)
    out[2, 1] = 2.0 * (y * z + w * x)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True)
def camera_space(means, i, viewmat):
    """Camera-space (x, y, z) of means[i] under the [3,4] world->camera matrix."""
    px, py, pz = float(means[i, 0]), float(means[i, 1]), float(means[i, 2])
    x = viewmat[0, 0] * px + viewmat[0, 1] * py + viewmat[0, 2] * pz + viewmat[0, 3]
    y = viewmat[1, 0] * px + viewmat[1, 1] * py + viewmat[1, 2] * pz + viewmat[1, 3]
    z = viewmat[2, 0] * px + viewmat[2, 1] * py + viewmat[2, 2] * pz + viewmat[2, 3]
    return x, y, z


@njit(cache=True)
def conjugate(rotation, matrix, out, scratch):
    """out = rotation @ matrix @ rotation^T (all [3,3]; rotation may be the [3,4] viewmat)."""
    for r in range(3):
        for c in range(3):
            scratch[r, c] = rotation[r, 0] * matrix[0, c] + rotation[r, 1] * matrix[1, c] + rotation[r, 2] * matrix[2, c]
    for r in range(3):
        for c in range(3):
            out[r, c] = scratch[r, 0] * rotation[c, 0] + scratch[r, 1] * rotation[c, 1] + scratch[r, 2] * rotation[c, 2]


@njit(cache=True)
def covariances(rq, scales, i, viewmat, cov, cov_c, scratch):
    """cov = R_q S^2 R_q^T (world) and cov_c = R_view cov R_view^T (camera), both [3,3]."""
    s0 = float(scales[i, 0]) ** 2
    s1 = float(scales[i, 1]) ** 2
    s2 = float(scales[i, 2]) ** 2
    for r in range(3):
        for c in range(3):
            cov[r, c] = rq[r, 0] * rq[c, 0] * s0 + rq[r, 1] * rq[c, 1] * s1 + rq[r, 2] * rq[c, 2] * s2
    conjugate(viewmat, cov, cov_c, scratch)


@njit(cache=True)
def clamped_xy(x, y, z, fx, fy, cx, cy, width, height):
    """(tx, ty, clamped_x, clamped_y): the camera-space x, y at which the EWA Jacobian is
    evaluated, limited to the field of view plus a margin, and whether each was clamped."""
    tan_x = 0.5 * width / fx
    tan_y = 0.5 * height / fy
    lim_x_pos = (width - cx) / fx + FOV_MARGIN * tan_x
    lim_x_neg = cx / fx + FOV_MARGIN * tan_x
    lim_y_pos = (height - cy) / fy + FOV_MARGIN * tan_y
    lim_y_neg = cy / fy + FOV_MARGIN * tan_y
    u = x / z
    v = y / z
    tx = z * min(lim_x_pos, max(-lim_x_neg, u))
    ty = z * min(lim_y_pos, max(-lim_y_neg, v))
    return tx, ty, u < -lim_x_neg or u > lim_x_pos, v < -lim_y_neg or v > lim_y_pos


@njit(cache=True)
def ewa_jacobian(z, tx, ty, fx, fy):
    """The non-zero entries (j00, j02, j11, j12) of J = [[j00, 0, j02], [0, j11, j12]], the
    Jacobian of the perspective projection at (tx, ty, z)."""
    return fx / z, -fx * tx / (z * z), fy / z, -fy * ty / (z * z)


@njit(cache=True)
def cov2d(cov_c, jacobian):
    """Entries (a, b, c) of J cov_c J^T ([[a, b], [b, c]]) for the [3,3] camera covariance."""
    j00, j02, j11, j12 = jacobian
    a = j00 * j00 * cov_c[0, 0] + 2.0 * j00 * j02 * cov_c[0, 2] + j02 * j02 * cov_c[2, 2]
    b = j00 * j11 * cov_c[0, 1] + j00 * j12 * cov_c[0, 2] + j02 * j11 * cov_c[2, 1] + j02 * j12 * cov_c[2, 2]
    c = j11 * j11 * cov_c[1, 1] + 2.0 * j11 * j12 * cov_c[1, 2] + j12 * j12 * cov_c[2, 2]
    return a, b, c


@njit(cache=True)
def conic(a0, b, c0, eps2d, antialiased):
    """Dilate the 2D covariance [[a0, b], [b, c0]] by eps2d I and invert it.

    Returns the conic (A, B, C) = (c, -b, a) / det, det = a c - b^2 of the dilated matrix
    and the antialiasing compensation sqrt(det_original / det) floored at MIN_COMPENSATION
    (1 when not antialiased). A det <= 0 (which the caller culls) returns zeros: numba raises
    ZeroDivisionError on a division by zero."""
    a = a0 + eps2d
    c = c0 + eps2d
    det = a * c - b * b
    if not det > 0.0:
        return 0.0, 0.0, 0.0, det, 1.0
    compensation = 1.0
    if antialiased:
        compensation = math.sqrt(max(MIN_COMPENSATION * MIN_COMPENSATION, (a0 * c0 - b * b) / det))
    return c / det, -b / det, a / det, det, compensation


@njit(cache=True)
def view_direction(means, i, campos):
    """Unit direction (ux, uy, uz) from the [3] camera centre to means[i], and the distance."""
    dx = float(means[i, 0]) - campos[0]
    dy = float(means[i, 1]) - campos[1]
    dz = float(means[i, 2]) - campos[2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    return dx / length, dy / length, dz / length, length


@njit(cache=True)
def sh_colour(sh, i, sh_degree, basis, ch):
    """Channel ch of 0.5 + sum_k basis_k(direction) sh[i, k, ch] before the clamp at 0; basis
    [K] must hold sh_basis(direction) already."""
    value = 0.5
    for k in range((sh_degree + 1) * (sh_degree + 1)):
        value += basis[k] * sh[i, k, ch]
    return value


@njit(cache=True)
def _project_one(i, gaussians, camera, settings, outputs, work):
    """Project Gaussian i; leaves radii[i] = 0 (and the other outputs untouched) when it is
    culled. Tuples: gaussians (means, quats, scales, opacities, sh); camera (viewmat, campos
    [3], fx, fy, cx, cy, width, height); settings (sh_degree, near, far, eps2d, antialiased);
    outputs (means2d, conics, depths, opacities_eff, colours, radii); work (q [4], rq, cov,
    cov_c, scratch [3,3], basis [K])."""
    means, quats, scales, opacities, sh = gaussians
    viewmat, campos, fx, fy, cx, cy, width, height = camera
    sh_degree, near, far, eps2d, antialiased = settings
    means2d, conics, depths, opacities_eff, colours, radii = outputs
    q, rq, cov, cov_c, scratch, basis = work
    radii[i, 0] = 0
    radii[i, 1] = 0
    x, y, z = camera_space(means, i, viewmat)
    if z < near or z > far:
        return
    unit_quaternion(quats, i, q)
    rotation(q, rq)
    covariances(rq, scales, i, viewmat, cov, cov_c, scratch)
    tx, ty, _, _ = clamped_xy(x, y, z, fx, fy, cx, cy, width, height)
    a0, b, c0 = cov2d(cov_c, ewa_jacobian(z, tx, ty, fx, fy))
    conic_a, conic_b, conic_c, det, compensation = conic(a0, b, c0, eps2d, antialiased)
    if not det > 0.0:
        return
    opacity = float(opacities[i]) * compensation
    if opacity < ALPHA_THRESHOLD:
        return
    # Beyond `extend` standard deviations alpha = opacity * exp(-sigma) < ALPHA_THRESHOLD.
    extend = min(GAUSSIAN_EXTEND, math.sqrt(2.0 * math.log(opacity / ALPHA_THRESHOLD)))
    rx = math.ceil(extend * math.sqrt(a0 + eps2d))
    ry = math.ceil(extend * math.sqrt(c0 + eps2d))
    if rx <= 0.0 and ry <= 0.0:
        return
    u = fx * x / z + cx
    v = fy * y / z + cy
    if u + rx <= 0.0 or u - rx >= width or v + ry <= 0.0 or v - ry >= height:
        return
    means2d[i, 0] = u
    means2d[i, 1] = v
    conics[i, 0] = conic_a
    conics[i, 1] = conic_b
    conics[i, 2] = conic_c
    depths[i] = z
    opacities_eff[i] = opacity
    radii[i, 0] = int(min(rx, 2.0**30))
    radii[i, 1] = int(min(ry, 2.0**30))
    ux, uy, uz, _ = view_direction(means, i, campos)
    sh_basis(sh_degree, ux, uy, uz, basis)
    for ch in range(3):
        colours[i, ch] = max(sh_colour(sh, i, sh_degree, basis, ch), 0.0)


@njit(cache=True, parallel=True)
def project_forward(
    means, quats, scales, opacities, sh, viewmat, fx, fy, cx, cy, width, height, sh_degree,
    near, far, eps2d, antialiased, means2d, conics, depths, opacities_eff, colours, radii,
):
    """Fill the outputs (layout in the module docstring) for every Gaussian; culled ones get
    radii 0 and keep whatever the other outputs held."""
    n = means.shape[0]
    gaussians = (means, quats, scales, opacities, sh)
    camera = (viewmat, camera_centre(viewmat), fx, fy, cx, cy, width, height)
    settings = (sh_degree, near, far, eps2d, antialiased)
    outputs = (means2d, conics, depths, opacities_eff, colours, radii)
    for chunk in prange((n + CHUNK - 1) // CHUNK):
        work = (
            np.empty(4), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)),
            np.empty((sh_degree + 1) * (sh_degree + 1)),
        )
        for i in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            _project_one(i, gaussians, camera, settings, outputs, work)
