"""Real spherical harmonics (degree 0-4, the 3DGS basis order) and their gradient, for numba.

`direction` is a unit vector (x, y, z). Basis k multiplies coefficient k of each channel.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from lumos3d_cli.io.gaussians import SH_C0
from lumos3d_cli.render.constants import SH_C1, SH_C2, SH_C3, SH_C4


@njit(cache=True, inline="always")
def sh_basis(degree: int, x: float, y: float, z: float, out: np.ndarray) -> None:
    """Fill out[:K] with the basis values, K = (degree + 1)^2."""
    out[0] = SH_C0
    if degree < 1:
        return
    out[1] = -SH_C1 * y
    out[2] = SH_C1 * z
    out[3] = -SH_C1 * x
    if degree < 2:
        return
    xx, yy, zz = x * x, y * y, z * z
    out[4] = SH_C2[0] * x * y
    out[5] = SH_C2[1] * y * z
    out[6] = SH_C2[2] * (2.0 * zz - xx - yy)
    out[7] = SH_C2[3] * x * z
    out[8] = SH_C2[4] * (xx - yy)
    if degree < 3:
        return
    out[9] = SH_C3[0] * y * (3.0 * xx - yy)
    out[10] = SH_C3[1] * x * y * z
    out[11] = SH_C3[2] * y * (4.0 * zz - xx - yy)
    out[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
    out[13] = SH_C3[4] * x * (4.0 * zz - xx - yy)
    out[14] = SH_C3[5] * z * (xx - yy)
    out[15] = SH_C3[6] * x * (xx - 3.0 * yy)
    if degree < 4:
        return
    out[16] = SH_C4[0] * x * y * (xx - yy)
    out[17] = SH_C4[1] * y * z * (3.0 * xx - yy)
    out[18] = SH_C4[2] * x * y * (7.0 * zz - 1.0)
    out[19] = SH_C4[3] * y * z * (7.0 * zz - 3.0)
    out[20] = SH_C4[4] * (zz * (35.0 * zz - 30.0) + 3.0)
    out[21] = SH_C4[5] * x * z * (7.0 * zz - 3.0)
    out[22] = SH_C4[6] * (xx - yy) * (7.0 * zz - 1.0)
    out[23] = SH_C4[7] * x * z * (xx - 3.0 * yy)
    out[24] = SH_C4[8] * (xx * (xx - 3.0 * yy) - yy * (3.0 * xx - yy))


@njit(cache=True, inline="always")
def sh_basis_gradient(degree: int, x: float, y: float, z: float, weights: np.ndarray) -> tuple:
    """Sum_k weights[k] * d(basis_k)/d(x, y, z), treating x, y, z as independent variables.

    The caller projects the result through the normalisation of the direction.
    """
    gx = 0.0
    gy = 0.0
    gz = 0.0
    if degree < 1:
        return gx, gy, gz
    gy -= SH_C1 * weights[1]
    gz += SH_C1 * weights[2]
    gx -= SH_C1 * weights[3]
    if degree < 2:
        return gx, gy, gz
    xx, yy, zz = x * x, y * y, z * z
    w = weights
    gx += SH_C2[0] * y * w[4]
    gy += SH_C2[0] * x * w[4]
    gy += SH_C2[1] * z * w[5]
    gz += SH_C2[1] * y * w[5]
    gx += -2.0 * SH_C2[2] * x * w[6]
    gy += -2.0 * SH_C2[2] * y * w[6]
    gz += 4.0 * SH_C2[2] * z * w[6]
    gx += SH_C2[3] * z * w[7]
    gz += SH_C2[3] * x * w[7]
    gx += 2.0 * SH_C2[4] * x * w[8]
    gy += -2.0 * SH_C2[4] * y * w[8]
    if degree < 3:
        return gx, gy, gz
    gx += 6.0 * SH_C3[0] * x * y * w[9]
    gy += SH_C3[0] * (3.0 * xx - 3.0 * yy) * w[9]
    gx += SH_C3[1] * y * z * w[10]
    gy += SH_C3[1] * x * z * w[10]
    gz += SH_C3[1] * x * y * w[10]
    gx += -2.0 * SH_C3[2] * x * y * w[11]
    gy += SH_C3[2] * (4.0 * zz - xx - 3.0 * yy) * w[11]
    gz += 8.0 * SH_C3[2] * y * z * w[11]
    gx += -6.0 * SH_C3[3] * x * z * w[12]
    gy += -6.0 * SH_C3[3] * y * z * w[12]
    gz += SH_C3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy) * w[12]
    gx += SH_C3[4] * (4.0 * zz - 3.0 * xx - yy) * w[13]
    gy += -2.0 * SH_C3[4] * x * y * w[13]
    gz += 8.0 * SH_C3[4] * x * z * w[13]
    gx += 2.0 * SH_C3[5] * x * z * w[14]
    gy += -2.0 * SH_C3[5] * y * z * w[14]
    gz += SH_C3[5] * (xx - yy) * w[14]
    gx += SH_C3[6] * (3.0 * xx - 3.0 * yy) * w[15]
    gy += -6.0 * SH_C3[6] * x * y * w[15]
    if degree < 4:
        return gx, gy, gz
    gx += SH_C4[0] * (3.0 * xx * y - yy * y) * w[16]
    gy += SH_C4[0] * (xx * x - 3.0 * x * yy) * w[16]
    gx += 6.0 * SH_C4[1] * x * y * z * w[17]
    gy += SH_C4[1] * (3.0 * xx * z - 3.0 * yy * z) * w[17]
    gz += SH_C4[1] * (3.0 * xx * y - yy * y) * w[17]
    gx += SH_C4[2] * y * (7.0 * zz - 1.0) * w[18]
    gy += SH_C4[2] * x * (7.0 * zz - 1.0) * w[18]
    gz += 14.0 * SH_C4[2] * x * y * z * w[18]
    gy += SH_C4[3] * z * (7.0 * zz - 3.0) * w[19]
    gz += SH_C4[3] * y * (21.0 * zz - 3.0) * w[19]
    gz += SH_C4[4] * (140.0 * zz * z - 60.0 * z) * w[20]
    gx += SH_C4[5] * z * (7.0 * zz - 3.0) * w[21]
    gz += SH_C4[5] * x * (21.0 * zz - 3.0) * w[21]
    gx += 2.0 * SH_C4[6] * x * (7.0 * zz - 1.0) * w[22]
    gy += -2.0 * SH_C4[6] * y * (7.0 * zz - 1.0) * w[22]
    gz += 14.0 * SH_C4[6] * z * (xx - yy) * w[22]
    gx += SH_C4[7] * (3.0 * xx * z - 3.0 * yy * z) * w[23]
    gy += -6.0 * SH_C4[7] * x * y * z * w[23]
    gz += SH_C4[7] * (xx * x - 3.0 * x * yy) * w[23]
    gx += SH_C4[8] * (4.0 * xx * x - 12.0 * x * yy) * w[24]
    gy += SH_C4[8] * (-12.0 * xx * y + 4.0 * yy * y) * w[24]
    return gx, gy, gz
