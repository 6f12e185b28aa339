"""Assign projected Gaussians to 16x16 tiles and sort each tile front to back.

Deterministic and parallel: Gaussians are split into chunks that count and then fill their
tile entries independently; within a tile, entries are ordered by (depth, Gaussian index).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from lumos3d_cli.render.constants import TILE_SIZE


@njit(cache=True, inline="always")
def tile_rectangle(u, v, rx, ry, tiles_x, tiles_y):
    """Tiles [x0, x1) x [y0, y1) touched by a Gaussian's bounding box (radius in pixels)."""
    x0 = min(max(int(math.floor((u - rx) / TILE_SIZE)), 0), tiles_x)
    x1 = min(max(int(math.ceil((u + rx) / TILE_SIZE)), 0), tiles_x)
    y0 = min(max(int(math.floor((v - ry) / TILE_SIZE)), 0), tiles_y)
    y1 = min(max(int(math.ceil((v + ry) / TILE_SIZE)), 0), tiles_y)
    return x0, x1, y0, y1


@njit(cache=True, parallel=True)
def _count_per_chunk(means2d, radii, tiles_x, tiles_y, chunk, counts):
    n = means2d.shape[0]
    for ci in prange(counts.shape[0]):
        for i in range(ci * chunk, min(n, (ci + 1) * chunk)):
            if radii[i, 0] <= 0 and radii[i, 1] <= 0:
                continue
            x0, x1, y0, y1 = tile_rectangle(means2d[i, 0], means2d[i, 1], radii[i, 0], radii[i, 1], tiles_x, tiles_y)
            for ty in range(y0, y1):
                for tx in range(x0, x1):
                    counts[ci, ty * tiles_x + tx] += 1


@njit(cache=True, parallel=True)
def _fill_per_chunk(means2d, radii, tiles_x, tiles_y, chunk, cursor, entries):
    n = means2d.shape[0]
    for ci in prange(cursor.shape[0]):
        for i in range(ci * chunk, min(n, (ci + 1) * chunk)):
            if radii[i, 0] <= 0 and radii[i, 1] <= 0:
                continue
            x0, x1, y0, y1 = tile_rectangle(means2d[i, 0], means2d[i, 1], radii[i, 0], radii[i, 1], tiles_x, tiles_y)
            for ty in range(y0, y1):
                for tx in range(x0, x1):
                    tile = ty * tiles_x + tx
                    entries[cursor[ci, tile]] = i
                    cursor[ci, tile] += 1


@njit(cache=True, parallel=True)
def _sort_tiles(tile_offsets, entries, depths):
    for tile in prange(tile_offsets.shape[0] - 1):
        start = tile_offsets[tile]
        end = tile_offsets[tile + 1]
        if end - start < 2:
            continue
        ids = entries[start:end].copy()
        keys = np.empty(end - start, dtype=np.float64)
        for j in range(end - start):
            keys[j] = depths[ids[j]]
        order = np.argsort(keys, kind="mergesort")  # stable: equal depths keep Gaussian order
        for j in range(end - start):
            entries[start + j] = ids[order[j]]


def bin_and_sort(
    means2d: np.ndarray, radii: np.ndarray, depths: np.ndarray, width: int, height: int, chunks: int
) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Return (tile_offsets [T+1], entries [I] Gaussian ids sorted per tile, tiles_x, tiles_y).

    Tile t covers entries[tile_offsets[t]:tile_offsets[t+1]], nearest first.
    """
    tiles_x = (width + TILE_SIZE - 1) // TILE_SIZE
    tiles_y = (height + TILE_SIZE - 1) // TILE_SIZE
    n = means2d.shape[0]
    chunks = max(1, min(chunks, n))
    chunk = (n + chunks - 1) // chunks if n else 1
    counts = np.zeros((chunks, tiles_x * tiles_y), dtype=np.int64)
    _count_per_chunk(means2d, radii, tiles_x, tiles_y, chunk, counts)
    per_tile = counts.sum(axis=0)
    tile_offsets = np.zeros(tiles_x * tiles_y + 1, dtype=np.int64)
    np.cumsum(per_tile, out=tile_offsets[1:])
    # Each chunk starts writing a tile where the previous chunks' entries for that tile end.
    cursor = tile_offsets[:-1][None, :] + np.cumsum(counts, axis=0) - counts
    entries = np.empty(int(tile_offsets[-1]), dtype=np.int64)
    _fill_per_chunk(means2d, radii, tiles_x, tiles_y, chunk, cursor, entries)
    _sort_tiles(tile_offsets, entries, depths)
    return tile_offsets, entries, tiles_x, tiles_y
