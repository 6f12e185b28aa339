"""Per-view quality of restored images against references: PSNR, PSNR at the reference's mean
grey level (eval.metrics.psnr_gt_mean), SSIM, sharpness (detail
energy over the reference's, eval.metrics.sharpness) and (with trunk weights) LPIPS; LPIPS
reports why it is missing instead of a number."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.eval.metrics import psnr, psnr_gt_mean, sharpness, ssim
from lumos3d_cli.io.image_files import list_images
from lumos3d_cli.io.images import read_image, to_srgb
from lumos3d_cli.losses.lpips import LPIPS


@dataclass
class QualityMeter:
    """Computes metrics of N images against N references (a [N, 3, H, W] batch or a sequence of
    [3, H, W], each image the size of its reference); lpips is None when it cannot be computed,
    with `lpips_note` saying why."""

    lpips: LPIPS | None
    lpips_note: str

    @staticmethod
    def create(lpips_weights: Path | str | None, network: str = "vgg") -> QualityMeter:
        trunk = "vgg16" if network == "vgg" else network
        if lpips_weights is None:
            return QualityMeter(None, f"LPIPS n/a: no LPIPS trunk weights given (a torchvision {trunk} weight file)")
        try:
            return QualityMeter(LPIPS(network, lpips_weights), f"LPIPS ({network})")
        except InputError as error:
            if error.parameter is not None:
                raise
            # named as the LPIPS weights: a damaged file reads as a damaged checkpoint would
            raise InputError(f"{error.detail}; give a torchvision {trunk} weight file", parameter="lpips_weights") from None
        except Exception as error:  # noqa: BLE001 - surfaced to the user as a clear message
            raise InputError(f"{lpips_weights}: {error}", parameter="lpips_weights") from error

    def measure(self, images: Sequence[torch.Tensor],
                references: Sequence[torch.Tensor]) -> list[dict[str, float | None]]:
        """Per image {psnr, psnr_gt_mean, ssim, sharpness, lpips}, in order; images of one size are measured as
        one batch."""
        if len(images) != len(references):
            raise ValueError(f"{len(images)} images for {len(references)} references")
        for index, (image, reference) in enumerate(zip(images, references)):
            if image.shape != reference.shape:
                raise ValueError(f"image {index} is {tuple(image.shape)} but its reference {tuple(reference.shape)}; "
                                 "each image must have its reference's size")
        rows: list[dict[str, float | None]] = [{} for _ in images]
        for size in dict.fromkeys(tuple(image.shape) for image in images):
            group = [i for i, image in enumerate(images) if tuple(image.shape) == size]
            measured = self._measure_batch(torch.stack([images[i] for i in group]),
                                           torch.stack([references[i] for i in group]))
            for i, row in zip(group, measured):
                rows[i] = row
        return rows

    def _measure_batch(self, images: torch.Tensor, references: torch.Tensor) -> list[dict[str, float | None]]:
        """images, references [N, 3, H, W]; the images are scored in float, clipped to [0, 1] (the
        range they are written in; an 8-bit PNG of them scores within 0.002 dB)."""
        images = images.clamp(0.0, 1.0)
        values_psnr = psnr(images, references).tolist()
        values_gt_mean = psnr_gt_mean(images, references).tolist()
        values_ssim = ssim(images, references).tolist()
        values_sharpness = sharpness(images, references).tolist()
        if self.lpips is not None:
            with torch.no_grad():
                values_lpips = [float(v) for v in self.lpips(images.float(), references.float())]
        else:
            values_lpips = [None] * len(values_psnr)
        return [{"psnr": p, "psnr_gt_mean": g, "ssim": s, "sharpness": d, "lpips": l}
                for p, g, s, d, l in zip(values_psnr, values_gt_mean, values_ssim, values_sharpness, values_lpips)]


def mean_metrics(rows: list[dict[str, float | None]],
                 keys: tuple[str, ...] = ("psnr", "psnr_gt_mean", "ssim", "sharpness", "lpips")) -> dict[str, float | None]:
    """The mean of each key over `rows`; None where any row lacks a value (or there is no row)."""
    return {k: (sum(r[k] for r in rows) / len(rows) if rows and all(r[k] is not None for r in rows) else None) for k in keys}


def load_references(folder: Path | str, names: list[str], sizes: Sequence[tuple[int, int]]) -> list[torch.Tensor]:
    """Reference photos with the same file stems as `names`, per view [3, H, W]; each must have
    its restored view's size (width, height) in `sizes`."""
    folder = Path(folder)
    if not folder.is_dir():
        what = "is a file, not a folder" if folder.exists() else "no such folder"
        raise InputError(f"{folder}: {what}; give the folder of reference photos, named as the inputs",
                         parameter="reference")
    # stems in any case, as --poses and eval match them (list_images refuses two that differ in case alone)
    available = {p.stem.casefold(): p for p in list_images(folder)}
    paths = []
    for name in names:
        stem = Path(name).stem
        if stem.casefold() not in available:
            raise InputError(f"{folder}: no image named {stem}.* for input {name}", parameter="reference")
        paths.append(available[stem.casefold()])
    references = []
    for name, path, (width, height) in zip(names, paths, sizes):
        pixels = to_srgb(read_image(path))
        if pixels.shape[:2] != (height, width):
            raise InputError(f"{path}: {pixels.shape[1]}x{pixels.shape[0]}, but input {name} is {width}x{height}; give "
                             "references of the same size", parameter="reference")
        references.append(torch.from_numpy(np.ascontiguousarray(pixels)).permute(2, 0, 1))
    return references
