"""Bracket samples in training: real under- or over-exposed photos (data/brackets.py) restored by
the network's predicted operator and scored against the bracket's well-exposed frame with the
appearance loss only (a bracket is one view: no geometry to learn from it). Their held-out split
is what validation reports for model selection."""

from __future__ import annotations

import math
import numpy as np
import torch

from lumos3d_cli.data.brackets import BRACKET_MODES, BracketDataset
from lumos3d_cli.errors import InputError
from lumos3d_cli.losses.appearance import appearance_loss
from lumos3d_cli.losses.ssim import ssim_map_mean
from lumos3d_cli.model.lumos3d import Lumos3D
from lumos3d_cli.train.config import BracketConfig


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
        modes = BRACKET_MODES if mode == "mixed" else (mode,)
        self.train = [BracketDataset(config.root, m, "train", size, crop_scale, flip=True, seed=seed) for m in modes]
        self.validation = [BracketDataset(config.root, m, "validation", size, (1.0, 1.0), flip=False, seed=seed) for m in modes]

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
    def scores(self, model: Lumos3D, device: torch.device) -> dict[str, float]:
        """Mean PSNR / SSIM of the first `validation_samples` held-out pairs restored at the network
        size: {"bracket_psnr", "bracket_ssim", "bracket_samples"}."""
        count = min(self.config.validation_samples, sum(len(d) for d in self.validation))
        psnrs, ssims = [], []
        for sample_id in range(count):
            inputs, targets = self._batch(self.validation, [sample_id])
            inputs, targets = inputs.to(device), targets.to(device)
            restored = model.predict_appearance(inputs).apply(inputs).clamp(0, 1)
            mse = float(torch.mean((restored.double() - targets.double()) ** 2))
            psnrs.append(10 * math.log10(1 / mse) if mse > 0 else math.inf)
            ssims.append(float(ssim_map_mean(restored.double(), targets.double()).mean()))
        return {"bracket_psnr": float(np.mean(psnrs)), "bracket_ssim": float(np.mean(ssims)), "bracket_samples": count}


def check_bracket_model(model: Lumos3D, config: BracketConfig) -> None:
    """InputError when bracket samples are configured for a model without an operator."""
    if config.root is not None and model.illumination_head is None:
        raise InputError(
            f"brackets.root is set but architecture '{model.architecture.name}' regresses colours; "
            "bracket samples train the appearance operator: use an 'operator' architecture (e.g. tiny-operator)"
        )
