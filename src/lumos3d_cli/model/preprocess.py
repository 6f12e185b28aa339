"""The one image preprocessing step of every command: resize (and optionally crop) photos to a
size the network accepts, and map intrinsics between network pixels and original pixels."""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from lumos3d_cli.checks import require_finite, require_unit_range
from lumos3d_cli.errors import InputError

MODES = ("resize", "crop")


@dataclass
class PreparedImages:
    """images [..., 3, H', W'] in [0, 1], H' and W' multiples of the patch size.

    A network pixel coordinate is u' = u * scale_x - offset_x (and likewise for v), with u the
    coordinate in the original image; exact in the project's pixel-corner convention.
    original_size and network_size are (width, height).
    """

    images: torch.Tensor
    original_size: tuple[int, int]
    network_size: tuple[int, int]
    scale: tuple[float, float]
    offset: tuple[float, float]

    def _affine(self, dtype, device) -> torch.Tensor:
        """[3, 3] map from original to network pixel coordinates."""
        (sx, sy), (ox, oy) = self.scale, self.offset
        return torch.tensor([[sx, 0.0, -ox], [0.0, sy, -oy], [0.0, 0.0, 1.0]], dtype=dtype, device=device)

    def intrinsics_to_original(self, intrinsics: torch.Tensor) -> torch.Tensor:
        """[..., 3, 3] intrinsics of the network image -> intrinsics of the original image."""
        return torch.linalg.inv(self._affine(torch.float64, intrinsics.device)).to(intrinsics.dtype) @ intrinsics

    def intrinsics_to_network(self, intrinsics: torch.Tensor) -> torch.Tensor:
        """[..., 3, 3] intrinsics of the original image -> intrinsics of the network image."""
        return self._affine(intrinsics.dtype, intrinsics.device) @ intrinsics


def network_size(width: int, height: int, image_size: int, patch_size: int, mode: str = "resize") -> tuple[int, int, int]:
    """(width', height', rows to crop from the resized height) for an image of width x height.

    "resize": the longer side becomes `image_size`, each side is rounded to the nearest multiple
    of the patch size (at least one patch); nothing is cropped, the aspect ratio changes by at
    most half a patch. "crop" (VGGT's default): the width becomes `image_size`, the height keeps
    the aspect ratio rounded to a patch multiple and is centre-cropped to `image_size` if taller.
    """
    if mode not in MODES:
        raise InputError(f"unknown preprocessing mode '{mode}'; choose one of: {', '.join(MODES)}")
    if width < 1 or height < 1:
        raise InputError(f"image size {width}x{height} is empty")
    if mode == "crop":
        resized_height = max(patch_size, round(height * (image_size / width) / patch_size) * patch_size)
        return image_size, min(resized_height, image_size), resized_height
    factor = image_size / max(width, height)
    new_width = max(patch_size, round(width * factor / patch_size) * patch_size)
    new_height = max(patch_size, round(height * factor / patch_size) * patch_size)
    return new_width, new_height, new_height


def prepare_images(images: torch.Tensor, image_size: int, patch_size: int, mode: str = "resize") -> PreparedImages:
    """images [..., 3, H, W] float in [0, 1] -> PreparedImages in the images' dtype (bicubic,
    antialiased, computed in float32 for float16 and bfloat16; clamped to [0, 1], where bicubic
    overshoots at edges). `image_size` and `patch_size` in pixels, image_size >= patch_size."""
    if images.dim() < 3 or images.shape[-3] != 3 or not images.is_floating_point():
        raise InputError(f"images must be float [..., 3, H, W], got {images.dtype} {tuple(images.shape)}")
    for name, value in (("patch_size", patch_size), ("image_size", image_size)):
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < (1 if name == "patch_size" else patch_size):
            raise InputError(f"{value!r}: give a whole number of pixels, at least "
                             f"{1 if name == 'patch_size' else f'the patch size {patch_size}'}", parameter=name)
    if images.numel() == 0:
        raise InputError(f"images: an empty batch {tuple(images.shape)}; give at least one image")
    require_finite("images", images)
    require_unit_range("images", images)
    height, width = images.shape[-2:]
    new_width, new_height, resized_height = network_size(width, height, image_size, patch_size, mode)
    flat = images.reshape(-1, 3, height, width)
    if flat.dtype in (torch.float16, torch.bfloat16):  # no bicubic kernel for them on the CPU
        flat = flat.float()
    if (new_width, resized_height) != (width, height):
        flat = F.interpolate(flat, size=(resized_height, new_width), mode="bicubic", antialias=True, align_corners=False)
    flat = flat.clamp(0.0, 1.0)
    top = (resized_height - new_height) // 2
    flat = flat[:, :, top : top + new_height]
    return PreparedImages(
        images=flat.reshape(*images.shape[:-3], 3, new_height, new_width).to(images.dtype),
        original_size=(width, height),
        network_size=(new_width, new_height),
        scale=(new_width / width, resized_height / height),
        offset=(0.0, float(top)),
    )
