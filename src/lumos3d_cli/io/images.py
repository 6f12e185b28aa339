"""Load photos, RAW and EXR files into one float32 RGB tensor for the model."""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from lumos3d_cli.io.colour import linear_to_srgb
from lumos3d_cli.io.hdr import probe_hdr, read_hdr
from lumos3d_cli.io.image_files import image_kind
from lumos3d_cli.io.image_types import DecodedImage, ImageHeader
from lumos3d_cli.io.photo import probe_photo, read_photo
from lumos3d_cli.io.raw import probe_raw, read_raw
from lumos3d_cli.io.scene_photos import list_photos

if TYPE_CHECKING:
    import torch

logger = logging.getLogger(__name__)

_READERS: dict[str, Callable[[Path], DecodedImage]] = {"photo": read_photo, "hdr": read_hdr, "raw": read_raw}
_PROBES: dict[str, Callable[[Path], ImageHeader]] = {"photo": probe_photo, "hdr": probe_hdr, "raw": probe_raw}


def read_image(path: Path | str) -> DecodedImage:
    """Decode one file of any supported kind (see `image_files`)."""
    path = Path(path)
    return _READERS[image_kind(path)](path)


def probe_image(path: Path | str) -> ImageHeader:
    """Read one file's header only."""
    path = Path(path)
    return _PROBES[image_kind(path)](path)


def to_srgb(image: DecodedImage) -> np.ndarray:
    """[H, W, 3] float32 sRGB in [0, 1]; linear sources are clipped to [0, 1] and encoded once."""
    if image.encoding == "srgb":
        return np.clip(image.pixels, 0.0, 1.0)
    for share, what in ((float((image.pixels > 1.0).mean()), "exceed 1.0"), (float((image.pixels < 0.0).mean()), "are negative")):
        if share > 0.01:  # a few out-of-gamut samples are usual; more is a file in another range
            logger.warning("%s: %.1f%% of linear samples %s and were clipped", image.path, 100 * share, what)
    return linear_to_srgb(np.clip(image.pixels, 0.0, 1.0))


def resize_image(pixels: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resize [H, W, C] float32: area averaging when shrinking, bilinear when enlarging."""
    if pixels.shape[1] == width and pixels.shape[0] == height:
        return pixels
    shrinking = width * height < pixels.shape[0] * pixels.shape[1]
    interpolation = cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR
    return cv2.resize(pixels, (width, height), interpolation=interpolation)


@dataclass
class LoadedPhotos:
    """Photos of one scene decoded, before any torch (`pipeline.early_registration` reads them
    while torch is still being imported).

    pixels: [V, 3, H, W] float32 sRGB in [0, 1], contiguous, every photo at the most common size
    (`ImageBatch`: a photo of another size is stretched to it); original_sizes: (width, height)
    of each file before any resize; originals: the photos of another size, [3, h, w] as decoded,
    by index.
    """

    pixels: np.ndarray
    paths: list[Path]
    original_sizes: list[tuple[int, int]]
    kinds: list[str]
    originals: dict[int, np.ndarray] = field(default_factory=dict)

    def batch(self) -> ImageBatch:
        """The same photos as a torch batch (sharing the pixels' memory)."""
        import torch  # here, not at the top: this module is read before torch is imported

        originals = {index: torch.from_numpy(photo) for index, photo in self.originals.items()}
        return ImageBatch(torch.from_numpy(self.pixels), self.paths, self.original_sizes, self.kinds, originals)


@dataclass
class ImageBatch:
    """Images of one scene in one working tensor.

    images: [V, 3, H, W] float32 sRGB in [0, 1], every photo at the most common size; a photo of
    another size is stretched to it (its aspect ratio changes: whatever measures geometry in it
    must map its pixels back with `original_sizes`, which the stretch keeps exact).
    original_sizes: (width, height) of each file before any resize. originals: the photos of
    another size as decoded, [3, h, w] by index (the stretched copy lost a larger photo's detail).
    """

    images: torch.Tensor
    paths: list[Path]
    original_sizes: list[tuple[int, int]]
    kinds: list[str]
    originals: dict[int, torch.Tensor] = field(default_factory=dict)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the tensor."""
        return int(self.images.shape[-1]), int(self.images.shape[-2])

    @property
    def mixed_sizes(self) -> bool:
        """True when some photo was stretched to the tensor's size."""
        return any(size != self.size for size in self.original_sizes)

    def photo(self, index: int) -> torch.Tensor:
        """[3, h, w] photo `index` at its own size, as decoded (a batch made without the
        originals: the working image resized back)."""
        width, height = self.original_sizes[index]
        if (width, height) == self.size:
            return self.images[index]
        if index in self.originals:
            return self.originals[index]
        import torch  # here, not at the top: this module is read before torch is imported

        pixels = resize_image(np.ascontiguousarray(self.images[index].permute(1, 2, 0).numpy()), width, height)
        return torch.from_numpy(pixels).permute(2, 0, 1)


def common_size(sizes: Sequence[tuple[int, int]]) -> tuple[int, int]:
    """The most frequent (width, height); ties go to the one seen first."""
    counts = Counter(sizes)
    best = max(counts.values())
    return next(size for size in sizes if counts[size] == best)


def load_images(
    inputs: Path | str | Sequence[Path | str],
    progress: Callable[[Path], None] | None = None,
) -> ImageBatch:
    """Load a folder or list of files into one batch; photos of other sizes are stretched to the
    most common size (`ImageBatch`). `progress` is called after each file."""
    return load_photos(inputs, progress).batch()


def load_photos(
    inputs: Path | str | Sequence[Path | str],
    progress: Callable[[Path], None] | None = None,
) -> LoadedPhotos:
    """`load_images` without torch: the photos as one numpy array (`LoadedPhotos`)."""
    paths = list_photos(inputs)
    pixels: list[np.ndarray] = []
    kinds: list[str] = []
    for path in paths:
        decoded = read_image(path)
        pixels.append(to_srgb(decoded))
        kinds.append(decoded.kind)
        if progress is not None:
            progress(path)
    sizes = [(p.shape[1], p.shape[0]) for p in pixels]
    width, height = common_size(sizes)
    mismatched = [path.name for path, size in zip(paths, sizes) if size != (width, height)]
    if mismatched:
        shown = ", ".join(mismatched[:5]) + (" ..." if len(mismatched) > 5 else "")
        logger.info(
            "%d of %d images differ in size and were stretched to %dx%d: %s",
            len(mismatched), len(paths), width, height, shown,
        )
    stacked = np.stack([resize_image(p, width, height) for p in pixels])
    originals = {index: np.ascontiguousarray(photo.transpose(2, 0, 1)) for index, photo in enumerate(pixels)
                 if sizes[index] != (width, height)}
    return LoadedPhotos(np.ascontiguousarray(stacked.transpose(0, 3, 1, 2)), paths, sizes, kinds, originals)
