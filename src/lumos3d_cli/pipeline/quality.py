"""Per-view quality of restored images against references: PSNR, SSIM and (with trunk weights)
LPIPS; LPIPS reports why it is missing instead of a number."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.eval.metrics import psnr, ssim
from lumos3d_cli.io.image_files import list_images
from lumos3d_cli.io.images import load_images
from lumos3d_cli.losses.lpips import LPIPS


@dataclass
class QualityMeter:
    """Computes metrics for [N, 3, H, W] batches; lpips is None when it cannot be computed, with
    `lpips_note` saying why."""

    lpips: LPIPS | None
    lpips_note: str

    @staticmethod
    def create(lpips_weights: Path | str | None, network: str = "vgg") -> QualityMeter:
        if lpips_weights is None:
            return QualityMeter(None, "LPIPS n/a: no LPIPS trunk weights given (a torchvision vgg16/alexnet weight file)")
        try:
            return QualityMeter(LPIPS(network, lpips_weights), f"LPIPS ({network})")
        except InputError:
            raise
        except Exception as error:  # noqa: BLE001 - surfaced to the user as a clear message
            raise InputError(f"{lpips_weights}: {error}", parameter="lpips_weights") from error

    def measure(self, images: torch.Tensor, references: torch.Tensor) -> list[dict[str, float | None]]:
        values_psnr = psnr(images, references).tolist()
        values_ssim = ssim(images, references).tolist()
        if self.lpips is not None:
            with torch.no_grad():
                values_lpips = [float(v) for v in self.lpips(images.float(), references.float())]
        else:
            values_lpips = [None] * len(values_psnr)
        return [{"psnr": p, "ssim": s, "lpips": l} for p, s, l in zip(values_psnr, values_ssim, values_lpips)]


def mean_metrics(rows: list[dict[str, float | None]], keys: tuple[str, ...] = ("psnr", "ssim", "lpips")) -> dict[str, float | None]:
    """The mean of each key over `rows`; None where any row lacks a value (or there is no row)."""
    return {k: (sum(r[k] for r in rows) / len(rows) if rows and all(r[k] is not None for r in rows) else None) for k in keys}


def load_references(folder: Path | str, names: list[str], size: tuple[int, int]) -> torch.Tensor:
    """Reference photos with the same file stems as `names`, [V, 3, H, W]; they must have the
    restored views' size (width, height)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: no such folder", parameter="reference")
    available = {p.stem: p for p in list_images(folder)}
    paths = []
    for name in names:
        stem = Path(name).stem
        if stem not in available:
            raise InputError(f"{folder}: no image named {stem}.* for input {name}", parameter="reference")
        paths.append(available[stem])
    batch = load_images(paths)
    if batch.size != size or len(set(batch.original_sizes)) != 1:
        width, height = batch.original_sizes[0]
        raise InputError(f"{folder}: images are {width}x{height}, the inputs {size[0]}x{size[1]}; give references of the "
                         "same size", parameter="reference")
    return batch.images
