"""Per-view quality of restored images against references: PSNR, SSIM and (with trunk weights)
LPIPS; LPIPS reports why it is missing instead of a number."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.eval.metrics import psnr, ssim
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
            return QualityMeter(None, "LPIPS n/a: no --lpips-weights given (a torchvision vgg16/alexnet weight file)")
        try:
            return QualityMeter(LPIPS(network, lpips_weights), f"LPIPS ({network})")
        except InputError:
            raise
        except Exception as error:  # noqa: BLE001 - surfaced to the user as a clear message
            raise InputError(f"--lpips-weights {lpips_weights}: {error}") from error

    def measure(self, images: torch.Tensor, references: torch.Tensor) -> list[dict[str, float | None]]:
        values_psnr = psnr(images, references).tolist()
        values_ssim = ssim(images, references).tolist()
        if self.lpips is not None:
            with torch.no_grad():
                values_lpips = [float(v) for v in self.lpips(images.float(), references.float())]
        else:
            values_lpips = [None] * len(values_psnr)
        return [{"psnr": p, "ssim": s, "lpips": l} for p, s, l in zip(values_psnr, values_ssim, values_lpips)]


def mean_metrics(rows: list[dict[str, float | None]]) -> dict[str, float | None]:
    keys = ("psnr", "ssim", "lpips")
    return {k: (sum(r[k] for r in rows) / len(rows) if rows and all(r[k] is not None for r in rows) else None) for k in keys}
