"""VGG-16/19 and AlexNet feature trunks in torchvision's layout (`features.<i>.weight`), so the
weight files users already have (e.g. `vgg19-dcbb9e9d.pth`) load directly. No weights are
bundled or downloaded: without a file these networks do not exist."""

from __future__ import annotations

import logging
from pathlib import Path

import torch
from torch import nn

from lumos3d_cli.io.state_dicts import check_shapes, read_state_dict

logger = logging.getLogger(__name__)

# Convolution widths per block ('M' = 2x2 max-pool), torchvision's configurations D and E.
_VGG_BLOCKS = {
    "vgg16": [[64, 64], [128, 128], [256, 256, 256], [512, 512, 512], [512, 512, 512]],
    "vgg19": [[64, 64], [128, 128], [256, 256, 256, 256], [512, 512, 512, 512], [512, 512, 512, 512]],
}
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class FeatureTrunk(nn.Module):
    """`features` is an nn.Sequential with torchvision's indices; `taps` maps a layer name
    (e.g. 'relu4_1') to the index of the module whose output it is. Inputs smaller than
    `min_size` (where the deepest layer would be empty) are upsampled to it first."""

    def __init__(self, name: str, features: nn.Sequential, taps: dict[str, int], min_size: int):
        super().__init__()
        self.name = name
        self.features = features
        self.taps = taps
        self.min_size = min_size

    def forward(self, images: torch.Tensor, layers: list[str]) -> dict[str, torch.Tensor]:
        """images [N, 3, H, W] (already normalised as the trunk expects) -> {layer: [N, C, h, w]}."""
        unknown = [layer for layer in layers if layer not in self.taps]
        if unknown:
            raise ValueError(f"{self.name} has no layer(s) {unknown}; choose from {list(self.taps)}")
        wanted = {self.taps[layer]: layer for layer in layers}
        outputs = {}
        height, width = images.shape[-2:]
        if min(height, width) < self.min_size:
            factor = self.min_size / min(height, width)
            size = (max(self.min_size, round(height * factor)), max(self.min_size, round(width * factor)))
            images = nn.functional.interpolate(images, size=size, mode="bilinear", align_corners=False)
        x = images
        for index, module in enumerate(self.features):
            x = module(x)
            if index in wanted:
                outputs[wanted[index]] = x
                if len(outputs) == len(wanted):
                    break
        return outputs


def _vgg(name: str) -> FeatureTrunk:
    modules: list[nn.Module] = []
    taps: dict[str, int] = {}
    channels = 3
    for block, widths in enumerate(_VGG_BLOCKS[name], start=1):
        for position, width in enumerate(widths, start=1):
            modules += [nn.Conv2d(channels, width, 3, padding=1), nn.ReLU()]
            taps[f"relu{block}_{position}"] = len(modules) - 1
            channels = width
        modules.append(nn.MaxPool2d(2, 2))
    return FeatureTrunk(name, nn.Sequential(*modules), taps, min_size=16)


def _alexnet() -> FeatureTrunk:
    features = nn.Sequential(
        nn.Conv2d(3, 64, 11, stride=4, padding=2), nn.ReLU(), nn.MaxPool2d(3, 2),
        nn.Conv2d(64, 192, 5, padding=2), nn.ReLU(), nn.MaxPool2d(3, 2),
        nn.Conv2d(192, 384, 3, padding=1), nn.ReLU(),
        nn.Conv2d(384, 256, 3, padding=1), nn.ReLU(),
        nn.Conv2d(256, 256, 3, padding=1), nn.ReLU(), nn.MaxPool2d(3, 2),
    )
    return FeatureTrunk("alexnet", features, {"relu1": 1, "relu2": 4, "relu3": 7, "relu4": 9, "relu5": 11}, min_size=32)


def build_trunk(name: str) -> FeatureTrunk:
    """An uninitialised trunk of the given architecture ('vgg16', 'vgg19', 'alexnet')."""
    if name in _VGG_BLOCKS:
        return _vgg(name)
    if name == "alexnet":
        return _alexnet()
    raise ValueError(f"unknown feature network {name!r}; use vgg16, vgg19 or alexnet")


def load_trunk(name: str, path: Path | str) -> FeatureTrunk:
    """Build the trunk and load `features.*` from a torchvision-layout file (classifier weights,
    if present, are ignored). Missing, unexpected or mis-shaped keys are an InputError."""
    trunk = build_trunk(name)
    state = read_state_dict(path)
    features = {k: v for k, v in state.items() if k.startswith("features.")}
    expected = {k: tuple(v.shape) for k, v in trunk.state_dict().items()}
    check_shapes(expected, {k: tuple(v.shape) for k, v in features.items()}, f"{path} (torchvision {name})")
    trunk.load_state_dict({k: v.float() for k, v in features.items()})
    ignored = len(state) - len(features)
    if ignored:
        logger.info("%s: ignored %d non-feature tensors (classifier)", path, ignored)
    trunk.eval().requires_grad_(False)
    return trunk


def imagenet_normalise(images: torch.Tensor) -> torch.Tensor:
    """[N, 3, H, W] in [0, 1] -> ImageNet-normalised input of torchvision trunks."""
    mean = torch.tensor(IMAGENET_MEAN, device=images.device, dtype=images.dtype)[:, None, None]
    std = torch.tensor(IMAGENET_STD, device=images.device, dtype=images.dtype)[:, None, None]
    return (images - mean) / std
