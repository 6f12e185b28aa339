"""A denser grid of pixel Gaussians than the network's: detail for views written at the photos' size.

The network predicts one Gaussian per network pixel (224 px on the longer side for the bundled
models), so a scene rendered at a 500 px photo can hold no more detail than that grid, however
sharp each Gaussian's colour is. A preset's `gaussian_grid` g > 1 makes the grid g times denser
(never denser than the photos): depth, opacity, rotation and fusion confidence are interpolated,
scales shrink by the same factor, and the colours are then taken from the photos over each finer
pixel's footprint (`model.appearance.footprint`). Depth is interpolated bilinearly on smooth
surfaces and by nearest neighbour across depth edges, where a blend would place Gaussians in the
empty space between a foreground and its background.
"""

from __future__ import annotations

from dataclasses import replace

import torch
import torch.nn.functional as F

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.model.gaussian_adapter import shrink_raw_scales
from lumos3d_cli.model.lumos3d import Lumos3DPrediction
from lumos3d_cli.pipeline.scene_geometry import SceneGeometry

# A fine pixel whose bilinear depth differs from its nearest network pixel's by more than this
# fraction lies on a depth edge: it keeps the nearest depth.
DEPTH_EDGE_TOLERANCE = 0.02


def dense_grid_size(network_size: tuple[int, int], photo_size: tuple[int, int], factor: float) -> tuple[int, int]:
    """(width, height) of a grid `factor` times the network's, no larger than the photo's."""
    (width, height), (photo_width, photo_height) = network_size, photo_size
    scale = max(1.0, min(factor, photo_width / width, photo_height / height))
    return round(width * scale), round(height * scale)


def upsample_depth(depth: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """depth [S, h, w] -> [S, H, W] at size (W, H): bilinear, nearest across depth edges."""
    width, height = size
    smooth = F.interpolate(depth[:, None].double(), size=(height, width), mode="bilinear", align_corners=False)[:, 0]
    nearest = F.interpolate(depth[:, None].double(), size=(height, width), mode="nearest")[:, 0]
    edge = (smooth - nearest).abs() > DEPTH_EDGE_TOLERANCE * nearest.abs()
    return torch.where(edge, nearest, smooth).to(depth.dtype)


def _resize_channels_last(values: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """[S, h, w, C] -> [S, H, W, C] bilinear at size (W, H)."""
    width, height = size
    resized = F.interpolate(values.permute(0, 3, 1, 2), size=(height, width), mode="bilinear", align_corners=False)
    return resized.permute(0, 2, 3, 1).contiguous()


def _rescaled_intrinsics(intrinsics: torch.Tensor, size: tuple[int, int], new_size: tuple[int, int]) -> torch.Tensor:
    """intrinsics [S, 3, 3] of images of `size` -> the same cameras' for images of `new_size`."""
    return Cameras(intrinsics.new_zeros(len(intrinsics), 3, 4), intrinsics, [size] * len(intrinsics)).rescaled(*new_size).intrinsics


def densify_grid(
    prediction: Lumos3DPrediction, geometry: SceneGeometry, size: tuple[int, int]
) -> tuple[Lumos3DPrediction, SceneGeometry]:
    """The prediction (one scene) and its geometry on a grid of `size` (width, height) instead of
    the network's: depth, raw parameters, confidence, fusion mask and network-pixel intrinsics
    follow, scales shrink with the pixels. The colours are left to the caller (they come from
    the photos, `pipeline.scene_stages.with_full_resolution_colours`)."""
    views, height, width = geometry.depth.shape
    new_width, new_height = size
    if (new_width, new_height) == (width, height):
        return prediction, geometry
    factor = ((new_width / width) * (new_height / height)) ** 0.5
    depth = upsample_depth(geometry.depth, size)
    params = shrink_raw_scales(_resize_channels_last(prediction.params[0], size), factor)[None]
    confidence = _resize_channels_last(prediction.confidence[0][..., None], size)[None, ..., 0]
    depth_confidence = _resize_channels_last(prediction.depth_conf[0][..., None], size)[None, ..., 0]
    intrinsics = _rescaled_intrinsics(geometry.network_intrinsics, (width, height), size)
    fuse_pixels = None
    if geometry.fuse_pixels is not None:
        fuse_pixels = F.interpolate(geometry.fuse_pixels[:, None].float(), size=(new_height, new_width), mode="nearest")[:, 0] > 0.5
    dense_prediction = replace(
        prediction, depth=depth[None].to(prediction.depth), depth_conf=depth_confidence, params=params,
        confidence=confidence, intrinsics=_rescaled_intrinsics(prediction.intrinsics[0], (width, height), size)[None],
    )
    dense_geometry = replace(geometry, depth=depth, network_intrinsics=intrinsics, fuse_pixels=fuse_pixels)
    return dense_prediction, dense_geometry
