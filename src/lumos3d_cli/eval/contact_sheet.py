"""Contact sheets: a grid of labelled image tiles (e.g. input | restored | reference per view)."""

from __future__ import annotations

import cv2
import numpy as np
import torch

_LABEL_HEIGHT = 22
_PADDING = 4


_TALLEST = 2  # a tile is at most this many tile widths tall: a 14x2000 strip once made a 137,220-px sheet


def _tile(image: torch.Tensor, width: int) -> np.ndarray:
    """[3, H, W] in [0, 1] -> uint8 [h, width, 3] (RGB): scaled to `width`, or to _TALLEST widths
    tall (a portrait strip), padded to `width` on the right."""
    pixels = image.detach().float().clamp(0, 1).permute(1, 2, 0).cpu().numpy()
    scale = min(width / pixels.shape[1], _TALLEST * width / pixels.shape[0])
    size = (max(1, min(width, round(pixels.shape[1] * scale))), max(1, round(pixels.shape[0] * scale)))
    resized = cv2.resize(pixels, size, interpolation=cv2.INTER_AREA)
    tile = np.round(resized * 255).astype(np.uint8)
    return np.pad(tile, ((0, 0), (0, width - tile.shape[1]), (0, 0)))


def _label(text: str, width: int) -> np.ndarray:
    strip = np.full((_LABEL_HEIGHT, width, 3), 32, np.uint8)
    cv2.putText(strip, text, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (235, 235, 235), 1, cv2.LINE_AA)
    return strip


def contact_sheet(rows: list[list[tuple[torch.Tensor, str]]], tile_width: int = 320) -> np.ndarray:
    """rows of (image [3, H, W], label) -> one RGB uint8 picture; tiles are scaled to
    `tile_width` and stacked, each with its label above it."""
    rendered_rows = []
    for row in rows:
        tiles = [np.concatenate([_label(text, tile_width), _tile(image, tile_width)]) for image, text in row]
        height = max(t.shape[0] for t in tiles)
        tiles = [np.pad(t, ((0, height - t.shape[0]), (0, _PADDING), (0, 0))) for t in tiles]
        rendered_rows.append(np.concatenate(tiles, axis=1))
    width = max(r.shape[1] for r in rendered_rows)
    rendered_rows = [np.pad(r, ((0, _PADDING), (0, width - r.shape[1]), (0, 0))) for r in rendered_rows]
    return np.concatenate(rendered_rows, axis=0)
