"""Front-to-back alpha compositing per 16x16 tile (forward, optionally with each tile entry's
rendered weight) and its hand-written backward.

Work is parallel over tiles. Inside a tile the loop runs over the tile's Gaussians (sorted
front to back) and, for each, over the pixels inside its bounding box only: outside the box its
alpha is provably below ALPHA_THRESHOLD (the radius is chosen so), so skipping those pixels
changes nothing. Per-pixel arithmetic is float64.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from lumos3d_cli.render.constants import ALPHA_THRESHOLD, MAX_ALPHA, TILE_SIZE, TRANSMITTANCE_THRESHOLD

_PIXELS = TILE_SIZE * TILE_SIZE
# Gradient columns per tile entry: d/d(u, v), d/d(conic A, B, C), d/d(opacity), d/d(rgb), d/d(depth).
GRADIENT_COLUMNS = 10


@njit(cache=True, inline="always")
def _pixel_box(u, v, rx, ry, x0, y0, x_end, y_end):
    """Pixel columns [j0, j1) and rows [i0, i1) of the tile whose centres lie within the radius."""
    j0 = max(x0, int(math.ceil(u - rx - 0.5)))
    j1 = min(x_end, int(math.floor(u + rx - 0.5)) + 1)
    i0 = max(y0, int(math.ceil(v - ry - 0.5)))
    i1 = min(y_end, int(math.floor(v + ry - 0.5)) + 1)
    return j0, j1, i0, i1


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
    speed)."""
    for tile in prange(tile_offsets.shape[0] - 1):
        x0 = (tile % tiles_x) * TILE_SIZE
        y0 = (tile // tiles_x) * TILE_SIZE
        x_end = min(x0 + TILE_SIZE, width)
        y_end = min(y0 + TILE_SIZE, height)
        pixel_count = (x_end - x0) * (y_end - y0)
        # A finished pixel stores its transmittance negated: one load tells both.
        transmittance = np.ones(_PIXELS)
        colour = np.zeros((_PIXELS, 3))
        depth = np.zeros(_PIXELS)
        last = np.full(_PIXELS, -1, dtype=np.int64)
        finished = 0
        for e in range(tile_offsets[tile], tile_offsets[tile + 1]):
            if finished == pixel_count:
                break
            g = entries[e]
            u = float(means2d[g, 0])
            v = float(means2d[g, 1])
            ca = float(conics[g, 0])
            cb = float(conics[g, 1])
            cc = float(conics[g, 2])
            opacity = float(opacities[g])
            sigma_limit = math.log(opacity / ALPHA_THRESHOLD)
            j0, j1, i0, i1 = _pixel_box(u, v, radii[g, 0], radii[g, 1], x0, y0, x_end, y_end)
            r = float(colours[g, 0])
            gr = float(colours[g, 1])
            b = float(colours[g, 2])
            z = float(depths[g])
            drawn = 0.0
            for i in range(i0, i1):
                dy = v - (i + 0.5)
                for j in range(j0, j1):
                    p = (i - y0) * TILE_SIZE + (j - x0)
                    t = transmittance[p]
                    if t < 0.0:
                        continue
                    dx = u - (j + 0.5)
                    sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                    if sigma < 0.0 or sigma > sigma_limit:
                        continue
                    alpha = min(MAX_ALPHA, opacity * math.exp(-sigma))
                    if alpha < ALPHA_THRESHOLD:
                        continue
                    next_t = t * (1.0 - alpha)
                    if next_t <= TRANSMITTANCE_THRESHOLD:
                        transmittance[p] = -t
                        finished += 1
                        continue
                    weight = alpha * t
                    colour[p, 0] += weight * r
                    colour[p, 1] += weight * gr
                    colour[p, 2] += weight * b
                    depth[p] += weight * z
                    drawn += weight
                    transmittance[p] = next_t
                    last[p] = e
            if out_entry_weights is not None:
                out_entry_weights[e] = drawn
        for i in range(y0, y_end):
            for j in range(x0, x_end):
                p = (i - y0) * TILE_SIZE + (j - x0)
                out_colour[i, j, 0] = colour[p, 0]
                out_colour[i, j, 1] = colour[p, 1]
                out_colour[i, j, 2] = colour[p, 2]
                out_depth[i, j] = depth[p]
                out_transmittance[i, j] = abs(transmittance[p])
                out_last[i, j] = last[p]


@njit(cache=True, parallel=True)
def rasterize_backward(
    tile_offsets, entries, tiles_x, width, height, means2d, conics, opacities, colours, depths, radii,
    transmittance_final, last_entry, v_colour, v_alpha, v_depth, entry_gradients,
):
    """Per-entry gradients [I, GRADIENT_COLUMNS] of the loss w.r.t. each Gaussian's 2D mean,
    conic, opacity, colour and depth, walking each tile back to front."""
    for tile in prange(tile_offsets.shape[0] - 1):
        start = tile_offsets[tile]
        x0 = (tile % tiles_x) * TILE_SIZE
        y0 = (tile // tiles_x) * TILE_SIZE
        x_end = min(x0 + TILE_SIZE, width)
        y_end = min(y0 + TILE_SIZE, height)
        transmittance = np.zeros(_PIXELS)
        final = np.zeros(_PIXELS)
        last = np.full(_PIXELS, -1, dtype=np.int64)
        grad_colour = np.zeros((_PIXELS, 3))
        grad_alpha = np.zeros(_PIXELS)
        grad_depth = np.zeros(_PIXELS)
        behind_colour = np.zeros((_PIXELS, 3))
        behind_depth = np.zeros(_PIXELS)
        newest = start - 1
        for i in range(y0, y_end):
            for j in range(x0, x_end):
                p = (i - y0) * TILE_SIZE + (j - x0)
                final[p] = transmittance_final[i, j]
                transmittance[p] = final[p]
                last[p] = last_entry[i, j]
                newest = max(newest, last[p])
                grad_colour[p, 0] = v_colour[i, j, 0]
                grad_colour[p, 1] = v_colour[i, j, 1]
                grad_colour[p, 2] = v_colour[i, j, 2]
                grad_alpha[p] = v_alpha[i, j]
                grad_depth[p] = v_depth[i, j]
        for e in range(newest, start - 1, -1):
            g = entries[e]
            u = float(means2d[g, 0])
            v = float(means2d[g, 1])
            ca = float(conics[g, 0])
            cb = float(conics[g, 1])
            cc = float(conics[g, 2])
            opacity = float(opacities[g])
            sigma_limit = math.log(opacity / ALPHA_THRESHOLD)
            c0 = float(colours[g, 0])
            c1 = float(colours[g, 1])
            c2 = float(colours[g, 2])
            z = float(depths[g])
            j0, j1, i0, i1 = _pixel_box(u, v, radii[g, 0], radii[g, 1], x0, y0, x_end, y_end)
            gu = gv = ga = gb = gc = gop = g0 = g1 = g2 = gz = 0.0
            for i in range(i0, i1):
                dy = v - (i + 0.5)
                for j in range(j0, j1):
                    p = (i - y0) * TILE_SIZE + (j - x0)
                    if e > last[p]:
                        continue
                    dx = u - (j + 0.5)
                    sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                    if sigma < 0.0 or sigma > sigma_limit:
                        continue
                    visibility = math.exp(-sigma)
                    alpha = min(MAX_ALPHA, opacity * visibility)
                    if alpha < ALPHA_THRESHOLD:
                        continue
                    ratio = 1.0 / (1.0 - alpha)
                    transmittance[p] *= ratio
                    t = transmittance[p]
                    weight = alpha * t
                    g0 += weight * grad_colour[p, 0]
                    g1 += weight * grad_colour[p, 1]
                    g2 += weight * grad_colour[p, 2]
                    gz += weight * grad_depth[p]
                    d_alpha = (
                        grad_colour[p, 0] * (c0 * t - behind_colour[p, 0] * ratio)
                        + grad_colour[p, 1] * (c1 * t - behind_colour[p, 1] * ratio)
                        + grad_colour[p, 2] * (c2 * t - behind_colour[p, 2] * ratio)
                        + grad_depth[p] * (z * t - behind_depth[p] * ratio)
                        + grad_alpha[p] * final[p] * ratio
                    )
                    if opacity * visibility <= MAX_ALPHA:
                        d_sigma = -opacity * visibility * d_alpha
                        ga += 0.5 * d_sigma * dx * dx
                        gb += d_sigma * dx * dy
                        gc += 0.5 * d_sigma * dy * dy
                        gu += d_sigma * (ca * dx + cb * dy)
                        gv += d_sigma * (cb * dx + cc * dy)
                        gop += visibility * d_alpha
                    behind_colour[p, 0] += c0 * weight
                    behind_colour[p, 1] += c1 * weight
                    behind_colour[p, 2] += c2 * weight
                    behind_depth[p] += z * weight
            entry_gradients[e, 0] = gu
            entry_gradients[e, 1] = gv
            entry_gradients[e, 2] = ga
            entry_gradients[e, 3] = gb
            entry_gradients[e, 4] = gc
            entry_gradients[e, 5] = gop
            entry_gradients[e, 6] = g0
            entry_gradients[e, 7] = g1
            entry_gradients[e, 8] = g2
            entry_gradients[e, 9] = gz


@njit(cache=True)
def gather_entry_gradients(entries, entry_gradients, out):
    """out[g] = sum of the rows of entry_gradients whose entry belongs to Gaussian g (in entry
    order, so the result does not depend on thread scheduling)."""
    for e in range(entries.shape[0]):
        g = entries[e]
        for k in range(entry_gradients.shape[1]):
            out[g, k] += entry_gradients[e, k]
