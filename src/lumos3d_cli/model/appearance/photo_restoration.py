"""Applying a scene's predicted operator to its photos at their full resolution: the restored
pixels that colour the Gaussians, so every detail of the input survives."""

from __future__ import annotations

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.colour import linear_to_srgb, luminance, srgb_to_linear
from lumos3d_cli.model.appearance.operator import AppearanceOperator

# One 8-bit step from black and from white (the exposure prior's empty scene; a monochrome photo).
BLACK_LEVEL = 1.0 / 255
WHITE_LEVEL = 254.0 / 255
# A frame whose pixels are all within this many 8-bit codes of black (or of white in every
# channel), in at most one level more, carries no image to restore (a lens cap's frame holds codes
# 0 to 2 of sensor noise): no gain brings back what was never recorded. A 16-bit or RAW frame that
# dark still holds hundreds of levels, an image, and is restored.
EMPTY_CODES = 2
# A monochrome photo's channels agree within one 8-bit step everywhere and, on average, within
# this share of its level: a dark 16-bit colour photo lies within one 8-bit step too, but its
# channels differ by a large share of their level.
MONOCHROME_SPREAD = 0.01


def _few_levels(view: torch.Tensor) -> bool:
    """Whether `view` (any shape, within EMPTY_CODES 8-bit codes of black or of white) takes at
    most EMPTY_CODES + 1 16-bit levels (a frame of 8-bit codes 0 to 2, say). O(pixels): a
    24-megapixel frame is not sorted."""
    levels = (view * 65535).round().long()
    levels = levels - levels.min()
    if int(levels.max()) > EMPTY_CODES * 257:  # the levels of codes 0..EMPTY_CODES are 257 apart
        return False
    return int((torch.bincount(levels.flatten()) > 0).sum()) <= EMPTY_CODES + 1


def frames_without_content(photos: torch.Tensor) -> tuple[list[int], list[int]]:
    """photos [V, 3, H, W] sRGB in [0, 1] at the photos' own size (a resized copy has more
    levels) -> (indices of all-black views, of all-saturated views): every pixel within
    EMPTY_CODES 8-bit codes of black (or of white), in at most EMPTY_CODES + 1 levels."""
    flat = photos.detach().reshape(photos.shape[0], -1)
    margin = EMPTY_CODES / 255 + 1e-6
    black = [view for view in (flat.amax(dim=1) <= margin).nonzero().flatten().tolist() if _few_levels(flat[view])]
    saturated = [view for view in (flat.amin(dim=1) >= 1 - margin).nonzero().flatten().tolist()
                 if _few_levels(flat[view])]
    return black, saturated


def is_monochrome(photo: torch.Tensor) -> bool:
    """photo [3, H, W] sRGB in [0, 1]: whether its channels agree (a greyscale file, or a grey
    photo saved as RGB): within one 8-bit step everywhere, and within MONOCHROME_SPREAD of its
    level on average."""
    spread = photo.detach().amax(dim=0) - photo.detach().amin(dim=0)
    return float(spread.max()) <= BLACK_LEVEL and float(spread.mean()) <= MONOCHROME_SPREAD * float(photo.mean())


def _grey(restored: torch.Tensor) -> torch.Tensor:
    """[3, H, W] sRGB -> the same image's linear luminance, sRGB-encoded in all three channels."""
    level = luminance(srgb_to_linear(restored.clamp(0.0, 1.0)))
    return linear_to_srgb(level).clamp(0.0, 1.0).expand_as(restored)


def restore_photos(photos: torch.Tensor, operator: AppearanceOperator) -> torch.Tensor:
    """photos [V, 3, H, W] sRGB in [0, 1] at any (full) resolution, the operator of their scene
    (B = 1; its local grids, if any, for the same V views, in the same order) -> restored sRGB
    [V, 3, H, W] float32 in [0, 1].

    One view at a time, so full-resolution photo sets fit in memory. A view that is all black or
    all saturated holds nothing to restore and stays black or white (the restore job warns of
    such photos by name, `frames_without_content`). A monochrome view (`is_monochrome`) holds
    no colour to restore: its restoration keeps its luminance and stays grey, where the operator's
    matrix, fitted to colour photos, would tint it.
    """
    if photos.dim() != 4 or photos.shape[1] != 3:
        raise InputError(f"photos to restore must be [V, 3, H, W], got shape {tuple(photos.shape)}")
    if operator.batch != 1:
        raise InputError(f"restore_photos takes the operator of one scene, got {operator.batch}; use operator.scene(i)")
    views = photos.shape[0]
    if operator.local_log2_gain is not None and operator.local_log2_gain.shape[1] != views:
        raise InputError(f"operator has local grids for {operator.local_log2_gain.shape[1]} views, but {views} photos were given")
    restored = torch.empty(photos.shape, dtype=torch.float32, device=photos.device)
    black, saturated = frames_without_content(photos)
    for view in range(views):
        if view in black or view in saturated:  # the operator's curve would turn white grey
            restored[view] = photos[view]
            continue
        restored[view] = operator.views(slice(view, view + 1)).apply(photos[view][None, None])[0, 0]
        if is_monochrome(photos[view]):
            restored[view] = _grey(restored[view])
    return restored
