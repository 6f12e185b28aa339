"""Random but reproducible test objects shared by several test modules."""

import torch

from lumos3d_cli.io.cameras import Cameras, make_intrinsics
from lumos3d_cli.io.gaussians import Gaussians, sh_coefficient_count
from lumos3d_cli.rotations import quaternion_to_matrix


def random_gaussians(n: int, degree: int, seed: int = 0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    k = sh_coefficient_count(degree)
    return Gaussians(
        means=torch.randn(n, 3, generator=g) * 3,
        quats=torch.randn(n, 4, generator=g),
        scales=torch.exp(torch.randn(n, 3, generator=g) - 3),
        opacities=torch.rand(n, generator=g),
        sh=torch.randn(n, k, 3, generator=g),
    )


def random_cameras(v: int, seed: int = 0) -> Cameras:
    g = torch.Generator().manual_seed(seed)
    rotation = quaternion_to_matrix(torch.randn(v, 4, generator=g, dtype=torch.float64))
    translation = torch.randn(v, 3, 1, generator=g, dtype=torch.float64)
    fx = 300 + 100 * torch.rand(v, generator=g, dtype=torch.float64)
    intrinsics = make_intrinsics(fx, fx * 1.01, torch.full((v,), 160.0), torch.full((v,), 120.5))
    return Cameras(torch.cat([rotation, translation], 2), intrinsics, [(320, 241)] * v, [f"{i}.png" for i in range(v)])

def camera_at_origin(width: int, height: int, focal: float | None = None) -> Cameras:
    focal = focal or 0.9 * width
    return Cameras(
        torch.eye(4, dtype=torch.float64)[:3][None], make_intrinsics(focal, focal, width / 2, height / 2), [(width, height)]
    )


def random_scene(n: int, seed: int, degree: int = 3, dtype=torch.float64, spread: float = 0.7, depth: float = 3.0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g, dtype=dtype) * spread
    means[:, 2] += depth
    return Gaussians(
        means=means,
        quats=torch.randn(n, 4, generator=g, dtype=dtype),
        scales=torch.rand(n, 3, generator=g, dtype=dtype) * 0.25 + 0.03,
        opacities=torch.rand(n, generator=g, dtype=dtype) * 0.9 + 0.05,
        sh=torch.randn(n, (degree + 1) ** 2, 3, generator=g, dtype=dtype) * 0.5,
    )


def save_random_trunk(name: str, path, seed: int = 0) -> None:
    """A torchvision-layout weight file for a VGG/AlexNet trunk with random weights (tests only)."""
    from lumos3d_cli.losses.feature_networks import build_trunk

    torch.manual_seed(seed)
    trunk = build_trunk(name)
    for module in trunk.features:
        if isinstance(module, torch.nn.Conv2d):
            torch.nn.init.kaiming_normal_(module.weight, nonlinearity="relu")
            torch.nn.init.uniform_(module.bias, -0.1, 0.1)
    state = dict(trunk.state_dict())
    state["classifier.0.weight"] = torch.zeros(4, 4)  # present in real torchvision files; ignored
    torch.save(state, path)
