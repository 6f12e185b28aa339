"""Front-to-back alpha compositing per 16x16 tile (forward, optionally with each tile entry's
rendered weight) and its hand-written backward.

Work is parallel over tiles. Inside a tile the loop runs over the tile's Gaussians (sorted
front to back) and, for each, over the rows of its bounding box; each row is one branch-free
pass over the tile's 16 pixel columns, which LLVM turns into SIMD code (on an AVX-512 machine
one register of float32, or two of float64). Every lane evaluates exp, so there is no cut-off on
sigma before it: skips are sigma < 0 and alpha < ALPHA_THRESHOLD, as in docs/rendering.md. Columns outside the box are masked, not skipped: outside the box
alpha is provably below ALPHA_THRESHOLD (the radius is chosen so), so masking them changes
nothing. The arithmetic runs in the inputs' precision (float32 renders in float32, as the
pure-torch twin does; float64 stays float64 for gradcheck), with every constant cast to it
(`_constants`): a bare Python float would promote float32 lanes to float64.

Three things keep those row loops vectorised and short (each measured on the compositing
kernel alone, 200k Gaussians at 512², while this was written; the old per-pixel branches with a
sigma cut-off before a scalar float64 exp were about 4x slower forward, 3x backward):
- exp is a polynomial (`_exp_neg`, Cody-Waite reduction + Cephes' minimax polynomial, within
  about one ulp of libm), since numba has no vector exp here (no SVML) and a libm call per pixel
  is scalar;
- all of a tile's per-pixel state lives in one array ([row, field, column]), so LLVM can tell
  the fields apart by their constant offsets instead of emitting runtime overlap checks between
  separate arrays before every row;
- nothing is reduced across the 16 columns inside the loop: the number of finished pixels is
  recounted once per block of entries, and per-entry sums (rendered weight, gradients) are
  kept per column and summed once per entry.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic, overload

from lumos3d_cli.render.constants import ALPHA_THRESHOLD, MAX_ALPHA, TILE_SIZE, TRANSMITTANCE_THRESHOLD

# Gradient columns per tile entry: d/d(u, v), d/d(conic A, B, C), d/d(opacity), d/d(rgb), d/d(depth).
GRADIENT_COLUMNS = 10
# Tile entries are read into a small contiguous buffer this many at a time: the random reads of
# the Gaussians' parameters then overlap one another instead of stalling each entry's pixel loop.
_BLOCK = 64
# Largest exponent handed to `_exp_neg`; exp(-80) is ~1.8e-35, so a clamped sigma still gives an
# alpha far below ALPHA_THRESHOLD, and 2^-n stays a normal float32.
_SIGMA_CLAMP = 80.0

# Columns of the per-block parameter buffer.
_U, _V, _CA, _CB, _CC, _OPACITY, _RED, _GREEN, _BLUE, _DEPTH = range(10)
_PARAMETERS = 10

# Per-pixel fields of the forward tile state [TILE_SIZE rows, fields, TILE_SIZE columns].
# _X holds the pixel centres' x (constant), _W the rendered weight of the current entry.
_F_T, _F_RED, _F_GREEN, _F_BLUE, _F_DEPTH, _F_W, _F_X = range(7)
_FORWARD_FIELDS = 8
# Per-pixel fields of the backward tile state: transmittance (walked back), final transmittance,
# the incoming gradients, the colour and depth composited behind the current entry, pixel x.
(_B_T, _B_FINAL, _B_GRAD_RED, _B_GRAD_GREEN, _B_GRAD_BLUE, _B_GRAD_ALPHA, _B_GRAD_DEPTH,
 _B_BEHIND_RED, _B_BEHIND_GREEN, _B_BEHIND_BLUE, _B_BEHIND_DEPTH, _B_X) = range(12)
_BACKWARD_FIELDS = 12
# Rows of the backward's per-column gradient accumulator (the order of GRADIENT_COLUMNS).
_G_U, _G_V, _G_A, _G_B, _G_C, _G_OPACITY, _G_RED, _G_GREEN, _G_BLUE, _G_DEPTH = range(GRADIENT_COLUMNS)


@intrinsic
def _float_from_bits(typingctx, bits):
    """The float whose IEEE-754 bit pattern is `bits` (int32 -> float32, int64 -> float64)."""
    if bits == types.int32:
        return types.float32(types.int32), lambda context, builder, sig, args: builder.bitcast(args[0], ir.FloatType())
    if bits == types.int64:
        return types.float64(types.int64), lambda context, builder, sig, args: builder.bitcast(args[0], ir.DoubleType())
    return None


def _exp_neg(x):
    """exp(-x) for 0 <= x <= _SIGMA_CLAMP, in x's precision (numba only: see the overload)."""
    raise NotImplementedError("_exp_neg is only callable from numba-compiled code")


# exp(-x) = 2^-n exp(y) with n = round(x / ln 2) and y = n ln 2 - x in [-ln2/2, ln2/2] (ln 2 split
# in two so that n ln 2 is exact), exp(y) by a polynomial, 2^-n built from its exponent bits.
# Branch free, so the pixel loops vectorise. float32: Cephes' expf minimax polynomial; float64:
# Taylor to degree 12 (truncation below 2e-16 on the interval). Measured against long double
# over [0, 80]: within 0.72 ulp in float32 and 1.6 ulp in float64 (libm: 0.5).
_EXPF_POLYNOMIAL = (1.9875691500e-4, 1.3981999507e-3, 8.3334519073e-3, 4.1665795894e-2, 1.6666665459e-1, 5.0000001201e-1)


@overload(_exp_neg, jit_options={"fastmath": {"contract"}})
def _exp_neg_overload(x):
    if x == types.float32:
        f = np.float32
        log2e, half, one = f(1.0 / math.log(2.0)), f(0.5), f(1.0)
        ln2_hi, ln2_lo = f(0.693359375), f(-2.12194440e-4)
        p0, p1, p2, p3, p4, p5 = (f(c) for c in _EXPF_POLYNOMIAL)

        def exp_neg_float32(x):
            n = np.int32(x * log2e + half)  # x >= 0: truncation rounds to nearest
            nf = np.float32(n)
            y = (nf * ln2_hi - x) + nf * ln2_lo
            p = p0
            p = p * y + p1
            p = p * y + p2
            p = p * y + p3
            p = p * y + p4
            p = p * y + p5
            p = p * y * y + y + one
            return p * _float_from_bits(np.int32((127 - n) << 23))

        return exp_neg_float32
    if x == types.float64:
        c = tuple(1.0 / math.factorial(k) for k in range(13))
        log2e, ln2_hi, ln2_lo = 1.0 / math.log(2.0), 6.93147180369123816490e-01, 1.90821492927058770002e-10

        def exp_neg_float64(x):
            n = np.int64(x * log2e + 0.5)
            nf = np.float64(n)
            y = (nf * ln2_hi - x) + nf * ln2_lo
            p = c[12]
            p = p * y + c[11]
            p = p * y + c[10]
            p = p * y + c[9]
            p = p * y + c[8]
            p = p * y + c[7]
            p = p * y + c[6]
            p = p * y + c[5]
            p = p * y + c[4]
            p = p * y + c[3]
            p = p * y + c[2]
            p = p * y + c[1]
            p = p * y + c[0]
            return p * _float_from_bits(np.int64((1023 - n) << 52))

        return exp_neg_float64
    return None


def _constants(like):
    """(0, 1/2, 1, MAX_ALPHA, ALPHA_THRESHOLD, TRANSMITTANCE_THRESHOLD, _SIGMA_CLAMP) in the
    float type of `like` (numba only: see the overload)."""
    raise NotImplementedError("_constants is only callable from numba-compiled code")


@overload(_constants)
def _constants_overload(like):
    if isinstance(like, types.Float):
        cast = np.float32 if like == types.float32 else np.float64
        values = tuple(
            cast(c) for c in (0.0, 0.5, 1.0, MAX_ALPHA, ALPHA_THRESHOLD, TRANSMITTANCE_THRESHOLD, _SIGMA_CLAMP)
        )
        return lambda like: values
    return None


@njit(cache=True, fastmath={"reassoc"})
def _lane_sum(values):
    """Sum of a [TILE_SIZE] vector in a fixed tree order (reassociation lets LLVM use vector
    adds; the order does not depend on the data or on threads)."""
    total = _constants(values[0])[0]
    for k in range(values.shape[0]):
        total += values[k]
    return total


@njit(cache=True, inline="always")
def _pixel_box(u, v, rx, ry, x0, y0, x_end, y_end):
    """Pixel columns [j0, j1) and rows [i0, i1) of the tile whose centres lie within the radius."""
    j0 = max(x0, int(math.ceil(u - rx - 0.5)))
    j1 = min(x_end, int(math.floor(u + rx - 0.5)) + 1)
    i0 = max(y0, int(math.ceil(v - ry - 0.5)))
    i1 = min(y_end, int(math.floor(v + ry - 0.5)) + 1)
    return j0, j1, i0, i1


@njit(cache=True, inline="always")
def _gather(entries, first, count, x0, y0, x_end, y_end, means2d, conics, opacities, colours, depths, radii, params, boxes):
    """params[n] [_PARAMETERS] and boxes[n] = (j0, j1, i0, i1) relative to the tile corner for
    entries[first + n], n < count. The first loop only copies, so its cache misses overlap."""
    for n in range(count):
        g = entries[first + n]
        params[n, _U] = means2d[g, 0]
        params[n, _V] = means2d[g, 1]
        params[n, _CA] = conics[g, 0]
        params[n, _CB] = conics[g, 1]
        params[n, _CC] = conics[g, 2]
        params[n, _OPACITY] = opacities[g]
        params[n, _RED] = colours[g, 0]
        params[n, _GREEN] = colours[g, 1]
        params[n, _BLUE] = colours[g, 2]
        params[n, _DEPTH] = depths[g]
        boxes[n, 0] = radii[g, 0]
        boxes[n, 1] = radii[g, 1]
    for n in range(count):
        j0, j1, i0, i1 = _pixel_box(
            float(params[n, _U]), float(params[n, _V]), boxes[n, 0], boxes[n, 1], x0, y0, x_end, y_end
        )
        boxes[n, 0] = j0 - x0
        boxes[n, 1] = j1 - x0
        boxes[n, 2] = i0 - y0
        boxes[n, 3] = i1 - y0


@njit(cache=True, parallel=True)
def rasterize_forward(
    tile_offsets, entries, tiles_x, width, height, means2d, conics, opacities, colours, depths, radii,
    out_colour, out_depth, out_transmittance, out_last, out_entry_weights,
):
    """out_colour [H,W,3] = sum w c; out_depth [H,W] = sum w z; out_transmittance [H,W] = T after
    the last contributor; out_last [H,W] = entry index of the last contributor (-1: none);
    out_entry_weights [I] = sum over the entry's tile pixels of w = alpha T (each entry belongs
    to one tile, so the slots need no atomics), or None: numba then compiles a version without
    the `is not None` branches, and the unused sum disappears with them (the plain render's
    speed). Computed in the precision of means2d (float32 or float64)."""
    dtype = means2d.dtype
    for tile in prange(tile_offsets.shape[0] - 1):
        x0 = (tile % tiles_x) * TILE_SIZE
        y0 = (tile // tiles_x) * TILE_SIZE
        x_end = min(x0 + TILE_SIZE, width)
        y_end = min(y0 + TILE_SIZE, height)
        pixel_count = (x_end - x0) * (y_end - y0)
        start = tile_offsets[tile]
        end = tile_offsets[tile + 1]
        params = np.empty((_BLOCK, _PARAMETERS), dtype)
        boxes = np.empty((_BLOCK, 4), np.int64)
        zero, half, one, max_alpha, alpha_threshold, transmittance_threshold, sigma_clamp = _constants(params[0, 0])
        # A finished pixel stores its transmittance negated: one load tells both.
        state = np.zeros((TILE_SIZE, _FORWARD_FIELDS, TILE_SIZE), dtype)
        # int32 lanes: half the width of int64 in the masked store of every row.
        last = np.full((TILE_SIZE, TILE_SIZE), -1, np.int32)
        row_centres = np.empty(TILE_SIZE, dtype)
        for i in range(TILE_SIZE):
            row_centres[i] = y0 + i + 0.5
            for k in range(TILE_SIZE):
                state[i, _F_T, k] = one
                state[i, _F_X, k] = x0 + k + 0.5
        for first in range(start, end, _BLOCK):
            finished = 0
            for i in range(TILE_SIZE):
                for k in range(TILE_SIZE):
                    finished += 1 if state[i, _F_T, k] < zero else 0
            if finished == pixel_count:
                break
            count = min(_BLOCK, end - first)
            _gather(entries, first, count, x0, y0, x_end, y_end, means2d, conics, opacities, colours, depths, radii, params, boxes)
            for n in range(count):
                e = first + n
                e32 = np.int32(e)
                u = params[n, _U]
                v = params[n, _V]
                ca = params[n, _CA]
                cb = params[n, _CB]
                cc = params[n, _CC]
                opacity = params[n, _OPACITY]
                r = params[n, _RED]
                gr = params[n, _GREEN]
                b = params[n, _BLUE]
                z = params[n, _DEPTH]
                k0 = boxes[n, 0]
                k1 = boxes[n, 1]
                for row in range(boxes[n, 2], boxes[n, 3]):
                    dy = v - row_centres[row]
                    s = state[row]
                    last_row = last[row]
                    for k in range(TILE_SIZE):
                        t = s[_F_T, k]
                        dx = u - s[_F_X, k]
                        sigma = half * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                        alpha = min(max_alpha, opacity * _exp_neg(min(max(sigma, zero), sigma_clamp)))
                        drawn = (k >= k0) & (k < k1) & (t >= zero) & (sigma >= zero) & (alpha >= alpha_threshold)
                        next_t = t * (one - alpha)
                        done = drawn & (next_t <= transmittance_threshold)
                        drawn = drawn & (next_t > transmittance_threshold)
                        weight = alpha * t if drawn else zero
                        s[_F_RED, k] += weight * r
                        s[_F_GREEN, k] += weight * gr
                        s[_F_BLUE, k] += weight * b
                        s[_F_DEPTH, k] += weight * z
                        if out_entry_weights is not None:
                            s[_F_W, k] += weight
                        s[_F_T, k] = next_t if drawn else (-t if done else t)
                        last_row[k] = e32 if drawn else last_row[k]
                if out_entry_weights is not None:
                    total = 0.0
                    for row in range(boxes[n, 2], boxes[n, 3]):
                        total += _lane_sum(state[row, _F_W])
                        state[row, _F_W, :] = zero
                    out_entry_weights[e] = total
        for i in range(y0, y_end):
            for j in range(x0, x_end):
                s = state[i - y0]
                k = j - x0
                out_colour[i, j, 0] = s[_F_RED, k]
                out_colour[i, j, 1] = s[_F_GREEN, k]
                out_colour[i, j, 2] = s[_F_BLUE, k]
                out_depth[i, j] = s[_F_DEPTH, k]
                out_transmittance[i, j] = abs(s[_F_T, k])
                out_last[i, j] = last[i - y0, k]


@njit(cache=True, parallel=True)
def rasterize_backward(
    tile_offsets, entries, tiles_x, width, height, means2d, conics, opacities, colours, depths, radii,
    transmittance_final, last_entry, v_colour, v_alpha, v_depth, entry_gradients,
):
    """Per-entry gradients [I, GRADIENT_COLUMNS] of the loss w.r.t. each Gaussian's 2D mean,
    conic, opacity, colour and depth, walking each tile back to front. transmittance_final and
    last_entry [H,W] as rasterize_forward wrote them; v_colour [H,W,3], v_alpha and v_depth
    [H,W] the incoming gradients. Computed in the precision of means2d."""
    dtype = means2d.dtype
    for tile in prange(tile_offsets.shape[0] - 1):
        start = tile_offsets[tile]
        x0 = (tile % tiles_x) * TILE_SIZE
        y0 = (tile // tiles_x) * TILE_SIZE
        x_end = min(x0 + TILE_SIZE, width)
        y_end = min(y0 + TILE_SIZE, height)
        params = np.empty((_BLOCK, _PARAMETERS), dtype)
        boxes = np.empty((_BLOCK, 4), np.int64)
        zero, half, one, max_alpha, alpha_threshold, _, sigma_clamp = _constants(params[0, 0])
        state = np.zeros((TILE_SIZE, _BACKWARD_FIELDS, TILE_SIZE), dtype)
        last = np.full((TILE_SIZE, TILE_SIZE), -1, np.int32)
        # Separate from `state`: LLVM checks one pair of arrays for overlap per row, not every
        # field of the same array against every other.
        sums = np.zeros((GRADIENT_COLUMNS, TILE_SIZE), dtype)
        row_centres = np.empty(TILE_SIZE, dtype)
        for i in range(TILE_SIZE):
            row_centres[i] = y0 + i + 0.5
            for k in range(TILE_SIZE):
                state[i, _B_X, k] = x0 + k + 0.5
        newest = start - 1
        for i in range(y0, y_end):
            for j in range(x0, x_end):
                s = state[i - y0]
                k = j - x0
                s[_B_T, k] = transmittance_final[i, j]
                s[_B_FINAL, k] = transmittance_final[i, j]
                s[_B_GRAD_RED, k] = v_colour[i, j, 0]
                s[_B_GRAD_GREEN, k] = v_colour[i, j, 1]
                s[_B_GRAD_BLUE, k] = v_colour[i, j, 2]
                s[_B_GRAD_ALPHA, k] = v_alpha[i, j]
                s[_B_GRAD_DEPTH, k] = v_depth[i, j]
                last[i - y0, k] = last_entry[i, j]
                newest = max(newest, last_entry[i, j])
        block_end = newest + 1
        while block_end > start:
            first = max(start, block_end - _BLOCK)
            count = block_end - first
            _gather(entries, first, count, x0, y0, x_end, y_end, means2d, conics, opacities, colours, depths, radii, params, boxes)
            for n in range(count - 1, -1, -1):
                e = first + n
                e32 = np.int32(e)
                u = params[n, _U]
                v = params[n, _V]
                ca = params[n, _CA]
                cb = params[n, _CB]
                cc = params[n, _CC]
                opacity = params[n, _OPACITY]
                c0 = params[n, _RED]
                c1 = params[n, _GREEN]
                c2 = params[n, _BLUE]
                z = params[n, _DEPTH]
                k0 = boxes[n, 0]
                k1 = boxes[n, 1]
                for row in range(boxes[n, 2], boxes[n, 3]):
                    dy = v - row_centres[row]
                    s = state[row]
                    last_row = last[row]
                    for k in range(TILE_SIZE):
                        dx = u - s[_B_X, k]
                        sigma = half * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                        visibility = _exp_neg(min(max(sigma, zero), sigma_clamp))
                        raw_alpha = opacity * visibility
                        alpha = min(max_alpha, raw_alpha)
                        drawn = (k >= k0) & (k < k1) & (e32 <= last_row[k]) & (sigma >= zero) & (alpha >= alpha_threshold)
                        ratio = one / (one - alpha)
                        t_after = s[_B_T, k]
                        t = t_after * ratio
                        weight = alpha * t if drawn else zero
                        g0 = s[_B_GRAD_RED, k]
                        g1 = s[_B_GRAD_GREEN, k]
                        g2 = s[_B_GRAD_BLUE, k]
                        gz = s[_B_GRAD_DEPTH, k]
                        d_alpha = (
                            g0 * (c0 * t - s[_B_BEHIND_RED, k] * ratio)
                            + g1 * (c1 * t - s[_B_BEHIND_GREEN, k] * ratio)
                            + g2 * (c2 * t - s[_B_BEHIND_BLUE, k] * ratio)
                            + gz * (z * t - s[_B_BEHIND_DEPTH, k] * ratio)
                            + s[_B_GRAD_ALPHA, k] * s[_B_FINAL, k] * ratio
                        )
                        # Where alpha is clamped at MAX_ALPHA it does not depend on sigma or opacity.
                        unclamped = drawn & (raw_alpha <= max_alpha)
                        d_sigma = -raw_alpha * d_alpha if unclamped else zero
                        sums[_G_RED, k] += weight * g0
                        sums[_G_GREEN, k] += weight * g1
                        sums[_G_BLUE, k] += weight * g2
                        sums[_G_DEPTH, k] += weight * gz
                        sums[_G_A, k] += half * d_sigma * dx * dx
                        sums[_G_B, k] += d_sigma * dx * dy
                        sums[_G_C, k] += half * d_sigma * dy * dy
                        sums[_G_U, k] += d_sigma * (ca * dx + cb * dy)
                        sums[_G_V, k] += d_sigma * (cb * dx + cc * dy)
                        sums[_G_OPACITY, k] += visibility * d_alpha if unclamped else zero
                        s[_B_T, k] = t if drawn else t_after
                        s[_B_BEHIND_RED, k] += c0 * weight
                        s[_B_BEHIND_GREEN, k] += c1 * weight
                        s[_B_BEHIND_BLUE, k] += c2 * weight
                        s[_B_BEHIND_DEPTH, k] += z * weight
                for column in range(GRADIENT_COLUMNS):
                    entry_gradients[e, column] = _lane_sum(sums[column])
                    sums[column, :] = zero
            block_end = first


@njit(cache=True)
def gather_entry_gradients(entries, entry_gradients, out):
    """out[g] = sum of the rows of entry_gradients whose entry belongs to Gaussian g (in entry
    order, so the result does not depend on thread scheduling)."""
    for e in range(entries.shape[0]):
        g = entries[e]
        for k in range(entry_gradients.shape[1]):
            out[g, k] += entry_gradients[e, k]
