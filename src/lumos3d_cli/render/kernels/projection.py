"""Per-Gaussian EWA projection (forward and hand-written backward), parallel over Gaussians.

Everything per Gaussian is computed in float64 whatever the storage dtype, which keeps
far-away scenes and huge or tiny scales well conditioned. Array layout:
means [N,3], quats [N,4] wxyz, scales [N,3], opacities [N], sh [N,K,3];
viewmat [3,4] world->camera; outputs means2d [N,2], conics [N,3] (A, B, C of the inverse 2D
covariance), depths [N], opacities_eff [N], colours [N,3], radii [N,2] (0 = culled).
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
from lumos3d_cli.render.kernels.sh import sh_basis, sh_basis_gradient

_CHUNK = 1024  # Gaussians per parallel work item; scratch arrays are allocated once per chunk


@njit(cache=True)
def _camera_centre(viewmat):
    """-R^T t of a [3,4] world->camera matrix."""
    centre = np.empty(3)
    for r in range(3):
        centre[r] = -(viewmat[0, r] * viewmat[0, 3] + viewmat[1, r] * viewmat[1, 3] + viewmat[2, r] * viewmat[2, 3])
    return centre


@njit(cache=True)
def _unit_quaternion(quats, i, out):
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
def _rotation(q, out):
    """out[3,3] = rotation matrix of the unit quaternion q (wxyz)."""
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
def _camera_space(means, i, viewmat):
    px, py, pz = float(means[i, 0]), float(means[i, 1]), float(means[i, 2])
    x = viewmat[0, 0] * px + viewmat[0, 1] * py + viewmat[0, 2] * pz + viewmat[0, 3]
    y = viewmat[1, 0] * px + viewmat[1, 1] * py + viewmat[1, 2] * pz + viewmat[1, 3]
    z = viewmat[2, 0] * px + viewmat[2, 1] * py + viewmat[2, 2] * pz + viewmat[2, 3]
    return x, y, z


@njit(cache=True)
def _conjugate(rotation, matrix, out, scratch):
    """out = rotation @ matrix @ rotation^T (3x3)."""
    for r in range(3):
        for c in range(3):
            scratch[r, c] = rotation[r, 0] * matrix[0, c] + rotation[r, 1] * matrix[1, c] + rotation[r, 2] * matrix[2, c]
    for r in range(3):
        for c in range(3):
            out[r, c] = scratch[r, 0] * rotation[c, 0] + scratch[r, 1] * rotation[c, 1] + scratch[r, 2] * rotation[c, 2]


@njit(cache=True)
def _conjugate_transposed(rotation, matrix, out, scratch):
    """out = rotation^T @ matrix @ rotation (3x3)."""
    for r in range(3):
        for c in range(3):
            scratch[r, c] = rotation[0, r] * matrix[0, c] + rotation[1, r] * matrix[1, c] + rotation[2, r] * matrix[2, c]
    for r in range(3):
        for c in range(3):
            out[r, c] = scratch[r, 0] * rotation[0, c] + scratch[r, 1] * rotation[1, c] + scratch[r, 2] * rotation[2, c]


@njit(cache=True)
def _covariances(rq, scales, i, viewmat, cov, cov_c, scratch):
    """cov = R_q S^2 R_q^T (world) and cov_c = R_view cov R_view^T (camera), both [3,3]."""
    s0 = float(scales[i, 0]) ** 2
    s1 = float(scales[i, 1]) ** 2
    s2 = float(scales[i, 2]) ** 2
    for r in range(3):
        for c in range(3):
            cov[r, c] = rq[r, 0] * rq[c, 0] * s0 + rq[r, 1] * rq[c, 1] * s1 + rq[r, 2] * rq[c, 2] * s2
    _conjugate(viewmat, cov, cov_c, scratch)


@njit(cache=True)
def _clamped_xy(x, y, z, fx, fy, cx, cy, width, height):
    """tx, ty (camera-space x, y at which the EWA Jacobian is evaluated, limited to the field of
    view plus a margin) and whether each was clamped."""
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
def _cov2d(cov_c, j00, j02, j11, j12):
    """Entries (a, b, c) of J cov_c J^T, J = [[j00, 0, j02], [0, j11, j12]]."""
    a = j00 * j00 * cov_c[0, 0] + 2.0 * j00 * j02 * cov_c[0, 2] + j02 * j02 * cov_c[2, 2]
    b = j00 * j11 * cov_c[0, 1] + j00 * j12 * cov_c[0, 2] + j02 * j11 * cov_c[2, 1] + j02 * j12 * cov_c[2, 2]
    c = j11 * j11 * cov_c[1, 1] + 2.0 * j11 * j12 * cov_c[1, 2] + j12 * j12 * cov_c[2, 2]
    return a, b, c


@njit(cache=True)
def _project_one(
    i, means, quats, scales, opacities, sh, viewmat, campos, fx, fy, cx, cy, width, height, sh_degree,
    near, far, eps2d, antialiased, means2d, conics, depths, opacities_eff, colours, radii, q, rq, cov, cov_c, basis,
    scratch,
):
    radii[i, 0] = 0
    radii[i, 1] = 0
    x, y, z = _camera_space(means, i, viewmat)
    if z < near or z > far:
        return
    _unit_quaternion(quats, i, q)
    _rotation(q, rq)
    _covariances(rq, scales, i, viewmat, cov, cov_c, scratch)
    tx, ty, _, _ = _clamped_xy(x, y, z, fx, fy, cx, cy, width, height)
    a, b, c = _cov2d(cov_c, fx / z, -fx * tx / (z * z), fy / z, -fy * ty / (z * z))
    det_original = a * c - b * b
    a += eps2d
    c += eps2d
    det = a * c - b * b
    if not det > 0.0:
        return
    compensation = 1.0
    if antialiased:
        compensation = math.sqrt(max(MIN_COMPENSATION * MIN_COMPENSATION, det_original / det))
    opacity = float(opacities[i]) * compensation
    if opacity < ALPHA_THRESHOLD:
        return
    # Beyond `extend` standard deviations alpha = opacity * exp(-sigma) < ALPHA_THRESHOLD.
    extend = min(GAUSSIAN_EXTEND, math.sqrt(2.0 * math.log(opacity / ALPHA_THRESHOLD)))
    rx = math.ceil(extend * math.sqrt(a))
    ry = math.ceil(extend * math.sqrt(c))
    if rx <= 0.0 and ry <= 0.0:
        return
    u = fx * x / z + cx
    v = fy * y / z + cy
    if u + rx <= 0.0 or u - rx >= width or v + ry <= 0.0 or v - ry >= height:
        return
    means2d[i, 0] = u
    means2d[i, 1] = v
    conics[i, 0] = c / det
    conics[i, 1] = -b / det
    conics[i, 2] = a / det
    depths[i] = z
    opacities_eff[i] = opacity
    radii[i, 0] = int(min(rx, 2.0**30))
    radii[i, 1] = int(min(ry, 2.0**30))
    dx = float(means[i, 0]) - campos[0]
    dy = float(means[i, 1]) - campos[1]
    dz = float(means[i, 2]) - campos[2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    sh_basis(sh_degree, dx / length, dy / length, dz / length, basis)
    for ch in range(3):
        value = 0.5
        for k in range((sh_degree + 1) * (sh_degree + 1)):
            value += basis[k] * sh[i, k, ch]
        colours[i, ch] = max(value, 0.0)


@njit(cache=True, parallel=True)
def project_forward(
    means, quats, scales, opacities, sh, viewmat, fx, fy, cx, cy, width, height, sh_degree,
    near, far, eps2d, antialiased, means2d, conics, depths, opacities_eff, colours, radii,
):
    n = means.shape[0]
    campos = _camera_centre(viewmat)
    for chunk in prange((n + _CHUNK - 1) // _CHUNK):
        q = np.empty(4)
        rq = np.empty((3, 3))
        cov = np.empty((3, 3))
        cov_c = np.empty((3, 3))
        basis = np.empty((sh_degree + 1) * (sh_degree + 1))
        scratch = np.empty((3, 3))
        for i in range(chunk * _CHUNK, min(n, (chunk + 1) * _CHUNK)):
            _project_one(
                i, means, quats, scales, opacities, sh, viewmat, campos, fx, fy, cx, cy, width, height, sh_degree,
                near, far, eps2d, antialiased, means2d, conics, depths, opacities_eff, colours, radii,
                q, rq, cov, cov_c, basis, scratch,
            )


@njit(cache=True)
def _project_one_backward(
    i, means, quats, scales, opacities, sh, viewmat, campos, fx, fy, cx, cy, width, height, sh_degree,
    eps2d, antialiased, v_means2d, v_conics, v_depths, v_opacities_eff, v_colours,
    v_means, v_quats, v_scales, v_opacities, v_sh, q, rq, cov, cov_c, basis, weights, scratch,
):
    x, y, z = _camera_space(means, i, viewmat)
    qnorm = _unit_quaternion(quats, i, q)
    _rotation(q, rq)
    _covariances(rq, scales, i, viewmat, cov, cov_c, scratch)
    tx, ty, clamped_x, clamped_y = _clamped_xy(x, y, z, fx, fy, cx, cy, width, height)
    j00, j02, j11, j12 = fx / z, -fx * tx / (z * z), fy / z, -fy * ty / (z * z)
    a0, b, c0 = _cov2d(cov_c, j00, j02, j11, j12)
    det_original = a0 * c0 - b * b
    a = a0 + eps2d
    c = c0 + eps2d
    det = a * c - b * b
    opacity = float(opacities[i])

    # Opacity and the antialiasing compensation sqrt(det_original / det).
    compensation = 1.0
    floored = False
    if antialiased:
        ratio = det_original / det
        floored = ratio < MIN_COMPENSATION * MIN_COMPENSATION
        compensation = math.sqrt(max(MIN_COMPENSATION * MIN_COMPENSATION, ratio))
    v_opacities[i] = float(v_opacities_eff[i]) * compensation
    v_compensation = float(v_opacities_eff[i]) * opacity

    # Conic (A, B, C) = (c, -b, a) / det  ->  dilated 2D covariance entries (a, b, c).
    v_ca, v_cb, v_cc = float(v_conics[i, 0]), float(v_conics[i, 1]), float(v_conics[i, 2])
    inv_det2 = 1.0 / (det * det)
    v_a = (-c * c * v_ca + b * c * v_cb - b * b * v_cc) * inv_det2
    v_b = (2.0 * b * c * v_ca - (det + 2.0 * b * b) * v_cb + 2.0 * a * b * v_cc) * inv_det2
    v_c = (-b * b * v_ca + a * b * v_cb - a * a * v_cc) * inv_det2
    if antialiased and not floored:
        factor = v_compensation * 0.5 / compensation * inv_det2
        v_a += factor * (c0 * det - det_original * c)
        v_c += factor * (a0 * det - det_original * a)
        v_b += factor * (-2.0 * b * (det - det_original))

    # cov2d = J cov_c J^T. With V the gradient as a symmetric 2x2 matrix:
    # v_cov_c = J^T V J and v_J = 2 V J cov_c.
    m00, m01, m11 = v_a, 0.5 * v_b, v_c
    jm = scratch
    jm[0, 0], jm[0, 1], jm[0, 2] = j00, 0.0, j02
    jm[1, 0], jm[1, 1], jm[1, 2] = 0.0, j11, j12
    v_cov_c = cov  # reuse: cov is not needed any more
    for r in range(3):
        for col in range(3):
            v_cov_c[r, col] = (
                jm[0, r] * (m00 * jm[0, col] + m01 * jm[1, col]) + jm[1, r] * (m01 * jm[0, col] + m11 * jm[1, col])
            )
    jc00 = j00 * cov_c[0, 0] + j02 * cov_c[2, 0]
    jc01 = j00 * cov_c[0, 1] + j02 * cov_c[2, 1]
    jc02 = j00 * cov_c[0, 2] + j02 * cov_c[2, 2]
    jc10 = j11 * cov_c[1, 0] + j12 * cov_c[2, 0]
    jc11 = j11 * cov_c[1, 1] + j12 * cov_c[2, 1]
    jc12 = j11 * cov_c[1, 2] + j12 * cov_c[2, 2]
    v_j00 = 2.0 * (m00 * jc00 + m01 * jc10)
    v_j02 = 2.0 * (m00 * jc02 + m01 * jc12)
    v_j11 = 2.0 * (m01 * jc01 + m11 * jc11)
    v_j12 = 2.0 * (m01 * jc02 + m11 * jc12)

    # Camera-space mean: projected centre, depth, and the Jacobian's dependence on x, y, z
    # (a clamped tx = z * limit depends on z instead of x).
    v_u, v_v = float(v_means2d[i, 0]), float(v_means2d[i, 1])
    z2 = z * z
    z3 = z2 * z
    v_x = fx / z * v_u
    v_y = fy / z * v_v
    v_z = -(fx * x * v_u + fy * y * v_v) / z2 + float(v_depths[i])
    v_z += -fx / z2 * v_j00 - fy / z2 * v_j11 + 2.0 * fx * tx / z3 * v_j02 + 2.0 * fy * ty / z3 * v_j12
    v_tx = -fx / z2 * v_j02
    v_ty = -fy / z2 * v_j12
    if clamped_x:
        v_z += v_tx * tx / z
    else:
        v_x += v_tx
    if clamped_y:
        v_z += v_ty * ty / z
    else:
        v_y += v_ty
    for r in range(3):
        v_means[i, r] = viewmat[0, r] * v_x + viewmat[1, r] * v_y + viewmat[2, r] * v_z

    # View-dependent colour: SH coefficients and the direction from the camera centre.
    dx = float(means[i, 0]) - campos[0]
    dy = float(means[i, 1]) - campos[1]
    dz = float(means[i, 2]) - campos[2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    ux, uy, uz = dx / length, dy / length, dz / length
    k_count = (sh_degree + 1) * (sh_degree + 1)
    sh_basis(sh_degree, ux, uy, uz, basis)
    for k in range(k_count):
        weights[k] = 0.0
    for ch in range(3):
        value = 0.5
        for k in range(k_count):
            value += basis[k] * sh[i, k, ch]
        v_colour = float(v_colours[i, ch]) if value >= 0.0 else 0.0  # colour = max(value, 0)
        for k in range(k_count):
            v_sh[i, k, ch] = basis[k] * v_colour
            weights[k] += sh[i, k, ch] * v_colour
    gx, gy, gz = sh_basis_gradient(sh_degree, ux, uy, uz, weights)
    radial = gx * ux + gy * uy + gz * uz
    v_means[i, 0] += (gx - radial * ux) / length
    v_means[i, 1] += (gy - radial * uy) / length
    v_means[i, 2] += (gz - radial * uz) / length

    # World covariance: v_cov = R_view^T v_cov_c R_view; cov = M M^T with M = R_q diag(s).
    v_cov = cov_c  # reuse: cov_c is not needed any more
    _conjugate_transposed(viewmat, v_cov_c, v_cov, scratch)
    for r in range(3):
        for col in range(r, 3):
            symmetric = v_cov[r, col] + v_cov[col, r]  # (v_cov + v_cov^T), used as v_M = (.) M
            v_cov[r, col] = symmetric
            v_cov[col, r] = symmetric
    v_rq = scratch
    for col in range(3):
        s = float(scales[i, col])
        v_s = 0.0
        for r in range(3):
            v_m = 0.0
            for k in range(3):
                v_m += v_cov[r, k] * rq[k, col] * s
            v_rq[r, col] = v_m * s
            v_s += rq[r, col] * v_m
        v_scales[i, col] = v_s
    if qnorm == 0.0:
        for r in range(4):
            v_quats[i, r] = 0.0
        return
    w, qx, qy, qz = q[0], q[1], q[2], q[3]
    g = v_rq
    v_w = 2.0 * (qx * (g[2, 1] - g[1, 2]) + qy * (g[0, 2] - g[2, 0]) + qz * (g[1, 0] - g[0, 1]))
    v_qx = 2.0 * (-2.0 * qx * (g[1, 1] + g[2, 2]) + qy * (g[1, 0] + g[0, 1]) + qz * (g[2, 0] + g[0, 2]) + w * (g[2, 1] - g[1, 2]))
    v_qy = 2.0 * (qx * (g[1, 0] + g[0, 1]) - 2.0 * qy * (g[0, 0] + g[2, 2]) + qz * (g[2, 1] + g[1, 2]) + w * (g[0, 2] - g[2, 0]))
    v_qz = 2.0 * (qx * (g[2, 0] + g[0, 2]) + qy * (g[2, 1] + g[1, 2]) - 2.0 * qz * (g[0, 0] + g[1, 1]) + w * (g[1, 0] - g[0, 1]))
    # Through the normalisation q / |q|: project out the radial part.
    dot = v_w * w + v_qx * qx + v_qy * qy + v_qz * qz
    v_quats[i, 0] = (v_w - dot * w) / qnorm
    v_quats[i, 1] = (v_qx - dot * qx) / qnorm
    v_quats[i, 2] = (v_qy - dot * qy) / qnorm
    v_quats[i, 3] = (v_qz - dot * qz) / qnorm


@njit(cache=True, parallel=True)
def project_backward(
    means, quats, scales, opacities, sh, viewmat, fx, fy, cx, cy, width, height, sh_degree,
    eps2d, antialiased, radii,
    v_means2d, v_conics, v_depths, v_opacities_eff, v_colours,
    v_means, v_quats, v_scales, v_opacities, v_sh,
):
    """Gradients w.r.t. the Gaussian parameters; culled Gaussians (radii 0) get zeros."""
    n = means.shape[0]
    campos = _camera_centre(viewmat)
    k_count = (sh_degree + 1) * (sh_degree + 1)
    for chunk in prange((n + _CHUNK - 1) // _CHUNK):
        q = np.empty(4)
        rq = np.empty((3, 3))
        cov = np.empty((3, 3))
        cov_c = np.empty((3, 3))
        scratch = np.empty((3, 3))
        basis = np.empty(k_count)
        weights = np.empty(k_count)
        for i in range(chunk * _CHUNK, min(n, (chunk + 1) * _CHUNK)):
            if radii[i, 0] <= 0 and radii[i, 1] <= 0:
                continue
            _project_one_backward(
                i, means, quats, scales, opacities, sh, viewmat, campos, fx, fy, cx, cy, width, height, sh_degree,
                eps2d, antialiased, v_means2d, v_conics, v_depths, v_opacities_eff, v_colours,
                v_means, v_quats, v_scales, v_opacities, v_sh, q, rq, cov, cov_c, basis, weights, scratch,
            )
