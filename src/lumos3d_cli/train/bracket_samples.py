"""Bracket samples in training: real under- or over-exposed photos (data/brackets.py) restored by
the network's predicted operator and scored against the bracket's well-exposed frame with the
appearance loss only (a bracket is one view: no geometry to learn from it). Their held-out split
is what validation reports for model selection."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

from lumos3d_cli.data.brackets import BracketDataset
from lumos3d_cli.data.modes import MODES
from lumos3d_cli.errors import InputError
from lumos3d_cli.losses.appearance import appearance_loss
from lumos3d_cli.losses.ssim import ssim_map_mean
from lumos3d_cli.model.lumos3d import Lumos3D
from lumos3d_cli.train.config import BracketConfig

# The held-out pairs are cropped to the network's aspect at a seeded position: a fixed seed, not
# the run's, so that runs of any seed (and benchmarks/appearance_ablation.py) score the same crops.
# With the run's seed, the bundled low-light model scored 24.98 dB in one run's validation and
# 24.37 in another's.
VALIDATION_SEED = 0


def restore_with_operator(model: Lumos3D, inputs: torch.Tensor) -> torch.Tensor:
    """The model's predicted operator applied to `inputs` [B, V, 3, H, W] (same shape)."""
    return model.predict_appearance(inputs).apply(inputs)


class BracketSamples:
    """The training and held-out bracket pairs of one mode ("mixed": both, alternating), at the
    network size.

    Sample ids of step s on rank r: (s * world_size + r) * batch_size + i, so every step of every
    rank draws its own pairs and a resumed run draws the same ones (as the multi-view samples).
    """

    def __init__(self, config: BracketConfig, mode: str, size: tuple[int, int], crop_scale: tuple[float, float], seed: int):
        if config.root is None:
            raise ValueError("BracketSamples needs brackets.root")
        self.config = config
        modes = MODES if mode == "mixed" else (mode,)
        train_inputs = "both" if config.well_exposed else "restore"
        self.train = [BracketDataset(config.root, m, "train", size, crop_scale, flip=True, seed=seed, inputs=train_inputs)
                      for m in modes]
        self.validation = [BracketDataset(config.root, m, "validation", size, (1.0, 1.0), flip=False, seed=VALIDATION_SEED)
                           for m in modes]
        self.validation_well_exposed = [
            BracketDataset(config.root, m, "validation", size, (1.0, 1.0), flip=False, seed=VALIDATION_SEED, inputs="well-exposed")
            for m in modes
        ]

    def _batch(self, datasets: list[BracketDataset], sample_ids: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
        """Sample id i -> dataset i mod (number of modes), its pair i div that -> inputs, targets [N, 1, 3, H, W]."""
        samples = []
        for sample_id in sample_ids:
            dataset = datasets[sample_id % len(datasets)]
            index = sample_id // len(datasets)
            dataset.set_epoch(index // len(dataset))
            samples.append(dataset[index % len(dataset)])
        return torch.stack([s["images"] for s in samples]), torch.stack([s["targets"] for s in samples])

    def loss(self, model: Lumos3D, step: int, rank: int, world_size: int, device: torch.device) -> torch.Tensor:
        """The appearance loss of this step's bracket batch (scalar, float32)."""
        size = self.config.batch_size
        first = (step * world_size + rank) * size
        inputs, targets = self._batch(self.train, list(range(first, first + size)))
        inputs, targets = inputs.to(device), targets.to(device)
        operator = model.predict_appearance(inputs)
        return appearance_loss(operator.apply(inputs), targets, self.config.ssim_weight)

    @torch.no_grad()
    def scores(self, model: Lumos3D, device: torch.device,
               restore: Callable[[Lumos3D, torch.Tensor], torch.Tensor] = restore_with_operator) -> dict[str, float]:
        """Mean PSNR / SSIM of the held-out pairs restored at the network size (every pair, or
        `validation_samples` per mode spread evenly over them, so every held-out bracket counts)
        by `restore` (model, inputs [1, 1, 3, H, W]) -> [1, 1, 3, H, W] (default: the model's operator):
        {"bracket_psnr", "bracket_ssim", "bracket_samples"} for the restoration pairs and
        {"bracket_well_exposed_psnr", "bracket_well_exposed_ssim", "bracket_well_exposed_samples"}
        for the well-exposed ones (how much the head disturbs a photo that needs little or nothing)."""
        restore_psnr, restore_ssim, count = self._scores(model, self.validation, device, restore)
        well_psnr, well_ssim, well_count = self._scores(model, self.validation_well_exposed, device, restore)
        return {"bracket_psnr": restore_psnr, "bracket_ssim": restore_ssim, "bracket_samples": count,
                "bracket_well_exposed_psnr": well_psnr, "bracket_well_exposed_ssim": well_ssim,
                "bracket_well_exposed_samples": well_count}

    def _scores(self, model: Lumos3D, datasets: list[BracketDataset], device: torch.device,
                restore: Callable[[Lumos3D, torch.Tensor], torch.Tensor]) -> tuple[float, float, int]:
        psnrs, ssims = [], []
        for dataset in datasets:
            for index in validation_indices(len(dataset), self.config.validation_samples):
                sample = dataset[int(index)]
                inputs, targets = sample["images"][None].to(device), sample["targets"][None].to(device)
                restored = restore(model, inputs).clamp(0, 1)
                # an input that is its own target can be returned exactly: PSNR capped at 100 dB
                mse = max(float(torch.mean((restored.double() - targets.double()) ** 2)), 1e-10)
                psnrs.append(10 * math.log10(1 / mse))
                ssims.append(float(ssim_map_mean(restored.double(), targets.double()).mean()))
        return float(np.mean(psnrs)), float(np.mean(ssims)), len(psnrs)


def validation_indices(count: int, limit: int | None) -> np.ndarray:
    """Indices of the held-out pairs validation scores: all `count` (limit None), or `limit` of
    them evenly spaced from the first to the last. The pairs are sorted by bracket, so spacing
    them (not taking the first `limit`) keeps every held-out bracket in a small validation."""
    if limit is None or limit >= count:
        return np.arange(count)
    return np.unique(np.linspace(0, count - 1, limit).round().astype(int))


def check_bracket_model(model: Lumos3D, config: BracketConfig) -> None:
    """InputError when bracket samples are configured for a model without an operator."""
    if config.root is not None and model.illumination_head is None:
        raise InputError(
            f"brackets.root is set but architecture '{model.architecture.name}' regresses colours; "
            "bracket samples train the appearance operator: use an 'operator' architecture (e.g. tiny-operator)"
        )
