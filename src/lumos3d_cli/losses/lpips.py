"""LPIPS (Zhang et al. 2018, v0.1) with a VGG-16 or AlexNet trunk.

The per-layer linear weights are the small files shipped in the `lpips` PyPI package
(`lpips/weights/v0.1/{vgg,alex}.pth`; install it with `pip install --no-deps lpips`, its code is
not imported); the trunk weights are a torchvision-layout file the user has
(`vgg16-397923af.pth`, `alexnet-owt-7be5be79.pth`)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import torch
from torch import nn

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.state_dicts import read_state_dict
from lumos3d_cli.losses.feature_networks import load_trunk

# Input scaling of LPIPS v0.1, applied to images in [-1, 1].
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
_LAYERS = {
    "vgg": ("vgg16", ["relu1_2", "relu2_2", "relu3_3", "relu4_3", "relu5_3"]),
    "alex": ("alexnet", ["relu1", "relu2", "relu3", "relu4", "relu5"]),
}


def packaged_linear_weights(network: str) -> Path:
    """Path of `lpips/weights/v0.1/<network>.pth` inside an installed lpips package."""
    spec = importlib.util.find_spec("lpips")
    if spec is None or not spec.submodule_search_locations:
        raise InputError(
            "LPIPS needs the linear-layer weights of the lpips package: run `pip install --no-deps lpips` "
            "(or pass the .pth file explicitly)"
        )
    path = Path(list(spec.submodule_search_locations)[0]) / "weights" / "v0.1" / f"{network}.pth"
    if not path.is_file():
        raise InputError(f"{path}: not found in the installed lpips package")
    return path


class LPIPS(nn.Module):
    """forward(a, b) with images [N, 3, H, W] in [0, 1] -> distances [N]."""

    def __init__(self, network: str, trunk_weights: Path | str, linear_weights: Path | str | None = None):
        super().__init__()
        if network not in _LAYERS:
            raise InputError(f"LPIPS network {network!r}: use 'vgg' or 'alex'")
        trunk_name, self.layers = _LAYERS[network]
        self.network = network
        self.trunk = load_trunk(trunk_name, trunk_weights)
        linear_path = Path(linear_weights) if linear_weights else packaged_linear_weights(network)
        state = read_state_dict(linear_path)
        self.linear = nn.ParameterList()
        with torch.no_grad():
            probe = self.trunk(torch.zeros(1, 3, 64, 64), self.layers)
        for index, layer in enumerate(self.layers):
            key = f"lin{index}.model.1.weight"
            if key not in state:
                raise InputError(f"{linear_path}: missing {key}; not an LPIPS v0.1 linear-weight file")
            channels = probe[layer].shape[1]
            weight = state[key].float()
            if tuple(weight.shape) != (1, channels, 1, 1):
                raise InputError(f"{linear_path}: {key} has shape {tuple(weight.shape)}, expected (1, {channels}, 1, 1)")
            self.linear.append(nn.Parameter(weight, requires_grad=False))
        self.register_buffer("shift", torch.tensor(_SHIFT)[None, :, None, None], persistent=False)
        self.register_buffer("scale", torch.tensor(_SCALE)[None, :, None, None], persistent=False)
        self.eval()

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        inputs = torch.cat([a, b]) * 2 - 1
        features = self.trunk((inputs - self.shift) / self.scale, self.layers)
        total = torch.zeros(a.shape[0], device=a.device, dtype=a.dtype)
        for layer, weight in zip(self.layers, self.linear):
            feature = features[layer]
            feature = feature / (feature.pow(2).sum(dim=1, keepdim=True).sqrt() + 1e-10)
            first, second = feature.chunk(2)
            difference = (first - second) ** 2
            total = total + nn.functional.conv2d(difference, weight).mean(dim=(1, 2, 3))
        return total
