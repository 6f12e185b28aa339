"""Assign projected Gaussians to 16x16 tiles, each tile's entries front to back.

Deterministic and parallel: the drawn Gaussians are sorted once by (depth, Gaussian index),
then split into chunks of that order that count and then fill their tile entries
independently; chunk c writes a tile's entries after those of chunks < c, so within a tile
entries are ordered by (depth, Gaussian index).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

from lumos3d_cli.render.constants import TILE_SIZE
from lumos3d_cli.render.kernels.radix_sort import stable_argsort_uint32


@njit(cache=True, inline="always")
def tile_rectangle(u, v, rx, ry, tiles_x, tiles_y):
    """Tiles [x0, x1) x [y0, y1) touched by a Gaussian's bounding box (radius in pixels)."""
    x0 = min(max(int(math.floor((u - rx) / TILE_SIZE)), 0), tiles_x)
    x1 = min(max(int(math.ceil((u + rx) / TILE_SIZE)), 0), tiles_x)
    y0 = min(max(int(math.floor((v - ry) / TILE_SIZE)), 0), tiles_y)
    y1 = min(max(int(math.ceil((v + ry) / TILE_SIZE)), 0), tiles_y)
    return x0, x1, y0, y1


@njit(cache=True, parallel=True)
def _count_per_chunk(order, means2d, radii, tiles_x, tiles_y, chunk, counts):
    """counts[c, t] = entries of tile t from Gaussians order[c * chunk:(c + 1) * chunk]."""
    n = order.shape[0]
    for ci in prange(counts.shape[0]):
        for s in range(ci * chunk, min(n, (ci + 1) * chunk)):
            i = order[s]
            x0, x1, y0, y1 = tile_rectangle(means2d[i, 0], means2d[i, 1], radii[i, 0], radii[i, 1], tiles_x, tiles_y)
            for ty in range(y0, y1):
                for tx in range(x0, x1):
                    counts[ci, ty * tiles_x + tx] += 1


@njit(cache=True, parallel=True)
def _fill_per_chunk(order, means2d, radii, tiles_x, tiles_y, chunk, cursor, entries):
    """Write each Gaussian of order[c * chunk:(c + 1) * chunk] into its tiles, in order."""
    n = order.shape[0]
    for ci in prange(cursor.shape[0]):
        for s in range(ci * chunk, min(n, (ci + 1) * chunk)):
            i = order[s]
            x0, x1, y0, y1 = tile_rectangle(means2d[i, 0], means2d[i, 1], radii[i, 0], radii[i, 1], tiles_x, tiles_y)
            for ty in range(y0, y1):
                for tx in range(x0, x1):
                    tile = ty * tiles_x + tx
                    entries[cursor[ci, tile]] = i
                    cursor[ci, tile] += 1


def front_to_back(radii: np.ndarray, depths: np.ndarray, threads: int = 1) -> np.ndarray:
    """Indices [M] int64 of the drawn Gaussians (radii [N,2] not both 0), sorted by (depth,
    index) from depths [N].

    float32 depths are sorted by a stable radix sort (kernels/radix_sort.py, `threads` chunks a
    pass) of their bits in an order-keeping form, the drawn Gaussians given in index order, so
    ties in depth fall to the index. float64 depths (tests, gradcheck) take numpy's stable argsort."""
    drawn = np.flatnonzero((radii[:, 0] > 0) | (radii[:, 1] > 0))
    if depths.dtype != np.float32:
        return drawn[np.argsort(depths[drawn], kind="stable")]
    bits = (depths + np.float32(0.0)).view(np.uint32)  # + 0.0 turns -0.0 into 0.0
    # IEEE-754 bits -> unsigned integers in the floats' order: negatives have all bits flipped,
    # the others only the sign bit.
    keys = np.where(bits >> np.uint32(31), ~bits, bits | np.uint32(0x80000000))
    return stable_argsort_uint32(keys, drawn, threads)


def bin_and_sort(
    means2d: np.ndarray, radii: np.ndarray, depths: np.ndarray, width: int, height: int, chunks: int
) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Return (tile_offsets [T+1], entries [I] Gaussian ids sorted per tile, tiles_x, tiles_y).

    Tile t covers entries[tile_offsets[t]:tile_offsets[t+1]], nearest first. The drawn
    Gaussians are sorted front to back once, then written into their tiles in that order, so
    every tile comes out sorted (one sort of N keys instead of a sort per tile of its entries:
    the per-tile sorts were most of the binning time).
    """
    tiles_x = (width + TILE_SIZE - 1) // TILE_SIZE
    tiles_y = (height + TILE_SIZE - 1) // TILE_SIZE
    order = front_to_back(radii, depths, numba.get_num_threads())
    n = order.shape[0]
    chunks = max(1, min(chunks, n))
    chunk = (n + chunks - 1) // chunks if n else 1
    counts = np.zeros((chunks, tiles_x * tiles_y), dtype=np.int64)
    _count_per_chunk(order, means2d, radii, tiles_x, tiles_y, chunk, counts)
    per_tile = counts.sum(axis=0)
    tile_offsets = np.zeros(tiles_x * tiles_y + 1, dtype=np.int64)
    np.cumsum(per_tile, out=tile_offsets[1:])
    # Each chunk starts writing a tile where the previous chunks' entries for that tile end.
    cursor = tile_offsets[:-1][None, :] + np.cumsum(counts, axis=0) - counts
    entries = np.empty(int(tile_offsets[-1]), dtype=np.int64)
    _fill_per_chunk(order, means2d, radii, tiles_x, tiles_y, chunk, cursor, entries)
    return tile_offsets, entries, tiles_x, tiles_y
