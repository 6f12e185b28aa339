"""Per-Gaussian EWA projection, forward and hand-written backward, parallel over Gaussians.

Everything per Gaussian is computed in float64 whatever the storage dtype, which keeps
far-away scenes and huge or tiny scales well conditioned. Array layout:
means [N,3], quats [N,4] wxyz, scales [N,3], opacities [N], sh [N,K,3];
viewmat [3,4] world->camera; outputs means2d [N,2], conics [N,3] (A, B, C of the inverse 2D
covariance), depths [N], opacities_eff [N], colours [N,3], radii [N,2] (0 = culled).

Backward: gradient arrays v_means [N,3], v_quats [N,4], v_scales [N,3], v_opacities [N],
v_sh [N,K,3] from those of the outputs. It recomputes the forward steps (small functions shared
by both passes) instead of storing [N]-sized intermediates, and chains named pieces, each the
adjoint of one forward step:

    conics, opacities_eff  --conic_backward-->         2D covariance (a, b, c)
    2D covariance          --cov2d_backward-->         camera covariance, EWA Jacobian J
    means2d, depths, J     --camera_mean_backward-->   camera-space mean (J's clamp included)
    colours                --sh_colour_backward-->     sh, mean (through the view direction)
    camera covariance      --covariance_backward-->    scales, rotation matrix R_q
    R_q                    --quaternion_backward-->    quaternion (through q / |q|)

Each piece takes and returns float64 scalars or small arrays; tests/render/test_projection_stages.py
holds every piece to autograd through the matching stage of the pure-torch twin (render/reference.py).

Forward and backward share this file because numba's cache (cache=True) is invalidated per
file: a backward kept in another file could run a stale cached copy of a forward step edited here.

The per-Gaussian steps that take arrays are inline="always": as separate calls, numba
increments and decrements the reference count of every array argument on every call (atomic
operations, a sixth of the projection's time), and inlined the projection takes ~40 % less time
with bitwise the same results. quaternion_backward stays a call: inlined next to
sh_basis_gradient (whose local `w` is an array, where quaternion_backward's `w` is a float)
numba 0.68 returned wrong quaternion gradients.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from lumos3d_cli.render.constants import (
    ALPHA_THRESHOLD,
    FOV_MARGIN,
    GAUSSIAN_EXTEND,
    MAX_RADIUS,
    MIN_COMPENSATION,
)
from lumos3d_cli.render.kernels.sh import sh_basis, sh_basis_gradient
from lumos3d_cli.rotations import DEGENERATE_QUATERNION_NORM

_CHUNK = 1024  # Gaussians per parallel work item; scratch arrays are allocated once per chunk


@njit(cache=True)
def camera_centre(viewmat):
    """[3] = -R^T t of a [3,4] world->camera matrix."""
    centre = np.empty(3)
    for r in range(3):
        centre[r] = -(viewmat[0, r] * viewmat[0, 3] + viewmat[1, r] * viewmat[1, 3] + viewmat[2, r] * viewmat[2, 3])
    return centre


@njit(cache=True, inline="always")
def unit_quaternion(quats, i, out):
    """out[:4] = normalised wxyz of quats[i]; returns the norm (0 for a degenerate quaternion,
    which is then treated as identity). In float64, the components divided by the largest first,
    so that no square overflows (a float32 quaternion of 1e20 once read as the identity)."""
    peak = 0.0
    for r in range(4):
        peak = max(peak, abs(np.float64(quats[i, r])))
    scaled = 0.0
    if peak > 0.0:
        for r in range(4):
            scaled += (np.float64(quats[i, r]) / peak) ** 2
    norm = peak * math.sqrt(scaled)
    if norm < DEGENERATE_QUATERNION_NORM:
        out[0], out[1], out[2], out[3] = 1.0, 0.0, 0.0, 0.0
        return 0.0
    for r in range(4):
        out[r] = np.float64(quats[i, r]) / peak / math.sqrt(scaled)
    return norm


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
def camera_space(means, i, viewmat):
    """Camera-space (x, y, z) of means[i] under the [3,4] world->camera matrix."""
    px, py, pz = float(means[i, 0]), float(means[i, 1]), float(means[i, 2])
    x = viewmat[0, 0] * px + viewmat[0, 1] * py + viewmat[0, 2] * pz + viewmat[0, 3]
    y = viewmat[1, 0] * px + viewmat[1, 1] * py + viewmat[1, 2] * pz + viewmat[1, 3]
    z = viewmat[2, 0] * px + viewmat[2, 1] * py + viewmat[2, 2] * pz + viewmat[2, 3]
    return x, y, z


@njit(cache=True, inline="always")
def conjugate(rotation, matrix, out, scratch):
    """out = rotation @ matrix @ rotation^T (all [3,3]; rotation may be the [3,4] viewmat)."""
    for r in range(3):
        for c in range(3):
            scratch[r, c] = rotation[r, 0] * matrix[0, c] + rotation[r, 1] * matrix[1, c] + rotation[r, 2] * matrix[2, c]
    for r in range(3):
        for c in range(3):
            out[r, c] = scratch[r, 0] * rotation[c, 0] + scratch[r, 1] * rotation[c, 1] + scratch[r, 2] * rotation[c, 2]


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
def cov2d(cov_c, jacobian):
    """Entries (a, b, c) of J cov_c J^T ([[a, b], [b, c]]) for the [3,3] camera covariance."""
    j00, j02, j11, j12 = jacobian
    a = j00 * j00 * cov_c[0, 0] + 2.0 * j00 * j02 * cov_c[0, 2] + j02 * j02 * cov_c[2, 2]
    b = j00 * j11 * cov_c[0, 1] + j00 * j12 * cov_c[0, 2] + j02 * j11 * cov_c[2, 1] + j02 * j12 * cov_c[2, 2]
    c = j11 * j11 * cov_c[1, 1] + 2.0 * j11 * j12 * cov_c[1, 2] + j12 * j12 * cov_c[2, 2]
    return a, b, c


@njit(cache=True, inline="always")
def jacobian_product(jacobian, matrix):
    """The entries (row 0, then row 1) of the 2x3 product J matrix[:, :3], J = [[j00, 0, j02],
    [0, j11, j12]] given as jacobian (j00, j02, j11, j12): J's zeros leave two terms an entry."""
    j00, j02, j11, j12 = jacobian
    return (
        j00 * matrix[0, 0] + j02 * matrix[2, 0], j00 * matrix[0, 1] + j02 * matrix[2, 1],
        j00 * matrix[0, 2] + j02 * matrix[2, 2], j11 * matrix[1, 0] + j12 * matrix[2, 0],
        j11 * matrix[1, 1] + j12 * matrix[2, 1], j11 * matrix[1, 2] + j12 * matrix[2, 2],
    )


@njit(cache=True, inline="always")
def projected_covariance(rq, scales, i, viewmat, jacobian):
    """Entries (a, b, c) of the 2D covariance J R_view R_q S^2 R_q^T R_view^T J^T, the same as
    cov2d(cov_c, jacobian) after `covariances`, through the 2x3 product M = J R_view R_q S and
    a, b, c = the entries of M M^T: a third of the multiplications, no [3,3] scratch (the
    forward pass needs only the 2D covariance; the backward keeps the 3x3 steps it differentiates)."""
    t00, t01, t02, t10, t11, t12 = jacobian_product(jacobian, viewmat)  # T = J R_view
    s0, s1, s2 = float(scales[i, 0]), float(scales[i, 1]), float(scales[i, 2])
    # M = T R_q S, column by column.
    m00 = (t00 * rq[0, 0] + t01 * rq[1, 0] + t02 * rq[2, 0]) * s0
    m01 = (t00 * rq[0, 1] + t01 * rq[1, 1] + t02 * rq[2, 1]) * s1
    m02 = (t00 * rq[0, 2] + t01 * rq[1, 2] + t02 * rq[2, 2]) * s2
    m10 = (t10 * rq[0, 0] + t11 * rq[1, 0] + t12 * rq[2, 0]) * s0
    m11 = (t10 * rq[0, 1] + t11 * rq[1, 1] + t12 * rq[2, 1]) * s1
    m12 = (t10 * rq[0, 2] + t11 * rq[1, 2] + t12 * rq[2, 2]) * s2
    return (m00 * m00 + m01 * m01 + m02 * m02, m00 * m10 + m01 * m11 + m02 * m12,
            m10 * m10 + m11 * m11 + m12 * m12)


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


@njit(cache=True, inline="always")
def view_direction(means, i, campos):
    """Unit direction (ux, uy, uz) from the [3] camera centre to means[i], and the distance."""
    dx = float(means[i, 0]) - campos[0]
    dy = float(means[i, 1]) - campos[1]
    dz = float(means[i, 2]) - campos[2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    return dx / length, dy / length, dz / length, length


@njit(cache=True, inline="always")
def sh_colour(sh, i, sh_degree, basis, ch):
    """Channel ch of 0.5 + sum_k basis_k(direction) sh[i, k, ch] before the clamp at 0; basis
    [K] must hold sh_basis(direction) already."""
    value = 0.5
    for k in range((sh_degree + 1) * (sh_degree + 1)):
        value += basis[k] * sh[i, k, ch]
    return value


@njit(cache=True, inline="always")
def _project_one(i, gaussians, camera, settings, outputs, work):
    """Project Gaussian i; leaves radii[i] = 0 (and the other outputs untouched) when it is
    culled. Tuples: gaussians (means, quats, scales, opacities, sh); camera (viewmat, campos
    [3], fx, fy, cx, cy, width, height); settings (sh_degree, near, far, eps2d, antialiased);
    outputs (means2d, conics, depths, opacities_eff, colours, radii); work (q [4], rq [3,3],
    basis [K])."""
    means, quats, scales, opacities, sh = gaussians
    viewmat, campos, fx, fy, cx, cy, width, height = camera
    sh_degree, near, far, eps2d, antialiased = settings
    means2d, conics, depths, opacities_eff, colours, radii = outputs
    q, rq, basis = work
    radii[i, 0] = 0
    radii[i, 1] = 0
    x, y, z = camera_space(means, i, viewmat)
    if z < near or z > far:
        return
    unit_quaternion(quats, i, q)
    rotation(q, rq)
    tx, ty, _, _ = clamped_xy(x, y, z, fx, fy, cx, cy, width, height)
    a0, b, c0 = projected_covariance(rq, scales, i, viewmat, ewa_jacobian(z, tx, ty, fx, fy))
    conic_a, conic_b, conic_c, det, compensation = conic(a0, b, c0, eps2d, antialiased)
    if not det > 0.0:
        return
    opacity = float(opacities[i]) * compensation
    if opacity < ALPHA_THRESHOLD:
        return
    # Beyond `extend` standard deviations alpha = opacity * exp(-sigma) < ALPHA_THRESHOLD.
    extend = min(GAUSSIAN_EXTEND, math.sqrt(2.0 * math.log(opacity / ALPHA_THRESHOLD)))
    # np.ceil keeps a float (numba's math.ceil returns an int64, which wraps past 9.2e18 px and
    # culled the largest Gaussians); the cap applies when the radius is stored, as in the reference.
    rx = np.ceil(extend * math.sqrt(a0 + eps2d))
    ry = np.ceil(extend * math.sqrt(c0 + eps2d))
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
    radii[i, 0] = int(min(rx, MAX_RADIUS))
    radii[i, 1] = int(min(ry, MAX_RADIUS))
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
    for chunk in prange((n + _CHUNK - 1) // _CHUNK):
        work = (np.empty(4), np.empty((3, 3)), np.empty((sh_degree + 1) * (sh_degree + 1)))
        for i in range(chunk * _CHUNK, min(n, (chunk + 1) * _CHUNK)):
            _project_one(i, gaussians, camera, settings, outputs, work)


@njit(cache=True)
def conic_backward(a0, b, c0, eps2d, antialiased, opacity, v_conic, v_opacity_eff):
    """Adjoint of `conic` and of opacity_eff = opacity * compensation.

    (a0, b, c0): the undilated 2D covariance [[a0, b], [b, c0]] (det of the dilated one > 0);
    v_conic: gradient (v_A, v_B, v_C) of the conic. Returns (v_a, v_b, v_c, v_opacity), v_b being
    the gradient w.r.t. the one scalar b (both off-diagonal entries)."""
    det_original = a0 * c0 - b * b
    a = a0 + eps2d
    c = c0 + eps2d
    det = a * c - b * b
    compensation = 1.0
    floored = False
    if antialiased:
        ratio = det_original / det
        floored = ratio < MIN_COMPENSATION * MIN_COMPENSATION
        compensation = math.sqrt(max(MIN_COMPENSATION * MIN_COMPENSATION, ratio))
    v_opacity = v_opacity_eff * compensation
    v_compensation = v_opacity_eff * opacity

    # (A, B, C) = (c, -b, a) / det; d(1/det) = -(c da + a dc - 2 b db) / det^2.
    v_ca, v_cb, v_cc = v_conic
    inv_det2 = 1.0 / (det * det)
    v_a = (-c * c * v_ca + b * c * v_cb - b * b * v_cc) * inv_det2
    v_b = (2.0 * b * c * v_ca - (det + 2.0 * b * b) * v_cb + 2.0 * a * b * v_cc) * inv_det2
    v_c = (-b * b * v_ca + a * b * v_cb - a * a * v_cc) * inv_det2
    if antialiased and not floored:  # a floored compensation is a constant
        factor = v_compensation * 0.5 / compensation * inv_det2
        v_a += factor * (c0 * det - det_original * c)
        v_c += factor * (a0 * det - det_original * a)
        v_b += factor * (-2.0 * b * (det - det_original))
    return v_a, v_b, v_c, v_opacity


@njit(cache=True, inline="always")
def cov2d_backward(cov_c, jacobian, v_cov2d, v_cov_c, jm):
    """Adjoint of cov2d = J cov_c J^T. With V = [[v_a, v_b/2], [v_b/2, v_c]] the gradient as a
    symmetric 2x2 matrix: v_cov_c [3,3] = J^T V J (written) and v_J = 2 V J cov_c, returned as
    (v_j00, v_j02, v_j11, v_j12). jacobian: (j00, j02, j11, j12); jm: [3,3] scratch."""
    j00, j02, j11, j12 = jacobian
    v_a, v_b, v_c = v_cov2d
    m00, m01, m11 = v_a, 0.5 * v_b, v_c
    jm[0, 0], jm[0, 1], jm[0, 2] = j00, 0.0, j02
    jm[1, 0], jm[1, 1], jm[1, 2] = 0.0, j11, j12
    for r in range(3):
        for col in range(3):
            v_cov_c[r, col] = (
                jm[0, r] * (m00 * jm[0, col] + m01 * jm[1, col]) + jm[1, r] * (m01 * jm[0, col] + m11 * jm[1, col])
            )
    jc00, jc01, jc02, jc10, jc11, jc12 = jacobian_product(jacobian, cov_c)
    v_j00 = 2.0 * (m00 * jc00 + m01 * jc10)
    v_j02 = 2.0 * (m00 * jc02 + m01 * jc12)
    v_j11 = 2.0 * (m01 * jc01 + m11 * jc11)
    v_j12 = 2.0 * (m01 * jc02 + m11 * jc12)
    return v_j00, v_j02, v_j11, v_j12


@njit(cache=True, inline="always")
def camera_mean_backward(x, y, z, fx, fy, clamp, v_mean2d, v_depth, v_jacobian):
    """Gradient (v_x, v_y, v_z) w.r.t. the camera-space mean from the projected centre
    (u, v) = (fx x / z + cx, fy y / z + cy), the depth z and the EWA Jacobian's entries.

    clamp: (tx, ty, clamped_x, clamped_y) from `clamped_xy` (a clamped tx = z * limit depends
    on z instead of x); v_mean2d: (v_u, v_v); v_jacobian: (v_j00, v_j02, v_j11, v_j12)."""
    tx, ty, clamped_x, clamped_y = clamp
    v_u, v_v = v_mean2d
    v_j00, v_j02, v_j11, v_j12 = v_jacobian
    z2 = z * z
    z3 = z2 * z
    v_x = fx / z * v_u
    v_y = fy / z * v_v
    v_z = -(fx * x * v_u + fy * y * v_v) / z2 + v_depth
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
    return v_x, v_y, v_z


@njit(cache=True, inline="always")
def sh_colour_backward(sh, i, sh_degree, direction, v_colours, v_sh, basis, weights):
    """Adjoint of colours[i] = max(0.5 + sum_k basis_k(u) sh[i, k], 0) with u = d / |d| the
    view direction, direction = (ux, uy, uz, |d|) from `view_direction`.

    Writes v_sh[i] ([K,3]); returns the gradient w.r.t. the mean (through d, the camera centre
    held fixed). basis, weights: [K] scratch."""
    ux, uy, uz, length = direction
    k_count = (sh_degree + 1) * (sh_degree + 1)
    sh_basis(sh_degree, ux, uy, uz, basis)
    for k in range(k_count):
        weights[k] = 0.0
    for ch in range(3):
        value = sh_colour(sh, i, sh_degree, basis, ch)
        v_colour = float(v_colours[i, ch]) if value >= 0.0 else 0.0  # colour = max(value, 0)
        for k in range(k_count):
            v_sh[i, k, ch] = basis[k] * v_colour
            weights[k] += sh[i, k, ch] * v_colour
    gx, gy, gz = sh_basis_gradient(sh_degree, ux, uy, uz, weights)
    # Through the normalisation u = d / |d|: project out the radial part.
    radial = gx * ux + gy * uy + gz * uz
    return (gx - radial * ux) / length, (gy - radial * uy) / length, (gz - radial * uz) / length


@njit(cache=True, inline="always")
def covariance_backward(viewmat, rq, scales, i, v_cov_c, v_cov, v_rq, scratch, v_scales):
    """Adjoint of cov_c = R_view M M^T R_view^T with M = R_q diag(scales[i]).

    v_cov_c: [3,3] gradient of the camera covariance (any, not necessarily symmetric). Writes
    v_scales[i] and v_rq ([3,3], the gradient w.r.t. R_q); v_cov and scratch: [3,3] scratch."""
    # v_cov = R_view^T v_cov_c R_view, then (v_cov + v_cov^T), which makes v_M = (.) M.
    for r in range(3):
        for c in range(3):
            scratch[r, c] = viewmat[0, r] * v_cov_c[0, c] + viewmat[1, r] * v_cov_c[1, c] + viewmat[2, r] * v_cov_c[2, c]
    for r in range(3):
        for c in range(3):
            v_cov[r, c] = scratch[r, 0] * viewmat[0, c] + scratch[r, 1] * viewmat[1, c] + scratch[r, 2] * viewmat[2, c]
    for r in range(3):
        for col in range(r, 3):
            symmetric = v_cov[r, col] + v_cov[col, r]
            v_cov[r, col] = symmetric
            v_cov[col, r] = symmetric
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


# Not inline="always": see the module docstring (numba mixed up its `w` with sh_basis_gradient's).
@njit(cache=True)
def quaternion_backward(q, qnorm, g, v_quats, i):
    """Adjoint of R_q = rotation(q / |q|): g [3,3] is the gradient w.r.t. R_q, q [4] the unit
    quaternion (wxyz) and qnorm |q| (0: degenerate, treated as the constant identity).
    Writes v_quats[i]."""
    if qnorm == 0.0:
        for r in range(4):
            v_quats[i, r] = 0.0
        return
    w, qx, qy, qz = q[0], q[1], q[2], q[3]
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


@njit(cache=True, inline="always")
def _project_one_backward(i, gaussians, camera, settings, cotangents, gradients, work):
    """Gradients of Gaussian i, recomputing the forward intermediates. Tuples: gaussians (means,
    quats, scales, opacities, sh); camera (viewmat, campos [3], fx, fy, cx, cy, width, height);
    settings (sh_degree, eps2d, antialiased); cotangents (v_means2d, v_conics, v_depths,
    v_opacities_eff, v_colours); gradients (v_means, v_quats, v_scales, v_opacities, v_sh);
    work (q [4], rq, cov, cov_c, v_cov_c, v_cov, v_rq, scratch [3,3], basis, weights [K])."""
    means, quats, scales, opacities, sh = gaussians
    viewmat, campos, fx, fy, cx, cy, width, height = camera
    sh_degree, eps2d, antialiased = settings
    v_means2d, v_conics, v_depths, v_opacities_eff, v_colours = cotangents
    v_means, v_quats, v_scales, v_opacities, v_sh = gradients
    q, rq, cov, cov_c, v_cov_c, v_cov, v_rq, scratch, basis, weights = work

    x, y, z = camera_space(means, i, viewmat)
    qnorm = unit_quaternion(quats, i, q)
    rotation(q, rq)
    covariances(rq, scales, i, viewmat, cov, cov_c, scratch)
    clamp = clamped_xy(x, y, z, fx, fy, cx, cy, width, height)
    jacobian = ewa_jacobian(z, clamp[0], clamp[1], fx, fy)
    a0, b, c0 = cov2d(cov_c, jacobian)

    v_conic = (float(v_conics[i, 0]), float(v_conics[i, 1]), float(v_conics[i, 2]))
    v_a, v_b, v_c, v_opacity = conic_backward(
        a0, b, c0, eps2d, antialiased, float(opacities[i]), v_conic, float(v_opacities_eff[i])
    )
    v_opacities[i] = v_opacity
    v_jacobian = cov2d_backward(cov_c, jacobian, (v_a, v_b, v_c), v_cov_c, scratch)
    v_mean2d = (float(v_means2d[i, 0]), float(v_means2d[i, 1]))
    v_x, v_y, v_z = camera_mean_backward(x, y, z, fx, fy, clamp, v_mean2d, float(v_depths[i]), v_jacobian)
    gx, gy, gz = sh_colour_backward(sh, i, sh_degree, view_direction(means, i, campos), v_colours, v_sh, basis, weights)
    # The camera-space gradient goes back to the world through R_view^T.
    v_means[i, 0] = viewmat[0, 0] * v_x + viewmat[1, 0] * v_y + viewmat[2, 0] * v_z + gx
    v_means[i, 1] = viewmat[0, 1] * v_x + viewmat[1, 1] * v_y + viewmat[2, 1] * v_z + gy
    v_means[i, 2] = viewmat[0, 2] * v_x + viewmat[1, 2] * v_y + viewmat[2, 2] * v_z + gz
    covariance_backward(viewmat, rq, scales, i, v_cov_c, v_cov, v_rq, scratch, v_scales)
    quaternion_backward(q, qnorm, v_rq, v_quats, i)


@njit(cache=True, parallel=True)
def project_backward(
    means, quats, scales, opacities, sh, viewmat, fx, fy, cx, cy, width, height, sh_degree,
    eps2d, antialiased, radii,
    v_means2d, v_conics, v_depths, v_opacities_eff, v_colours,
    v_means, v_quats, v_scales, v_opacities, v_sh,
):
    """Gradients w.r.t. the Gaussian parameters from those of the projection's outputs (the
    v_* inputs, layouts as project_forward's outputs); culled Gaussians (radii 0) are skipped,
    so their rows keep the zeros the caller allocated."""
    n = means.shape[0]
    k_count = (sh_degree + 1) * (sh_degree + 1)
    gaussians = (means, quats, scales, opacities, sh)
    camera = (viewmat, camera_centre(viewmat), fx, fy, cx, cy, width, height)
    settings = (sh_degree, eps2d, antialiased)
    cotangents = (v_means2d, v_conics, v_depths, v_opacities_eff, v_colours)
    gradients = (v_means, v_quats, v_scales, v_opacities, v_sh)
    for chunk in prange((n + _CHUNK - 1) // _CHUNK):
        work = (
            np.empty(4), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)),
            np.empty((3, 3)), np.empty((3, 3)), np.empty(k_count), np.empty(k_count),
        )
        for i in range(chunk * _CHUNK, min(n, (chunk + 1) * _CHUNK)):
            if radii[i, 0] <= 0 and radii[i, 1] <= 0:
                continue
            _project_one_backward(i, gaussians, camera, settings, cotangents, gradients, work)
