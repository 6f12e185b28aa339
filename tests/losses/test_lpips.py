"""LPIPS: our loader and formula against the lpips package's own implementation (its code, run
with our trunk weights through a stand-in for torchvision, which has no CPU build here)."""

import importlib
import importlib.util
import sys
import types

import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.losses import lpips as lpips_module
from lumos3d_cli.losses.feature_networks import load_trunk
from lumos3d_cli.losses.lpips import LPIPS, packaged_linear_weights

from factories import save_random_trunk

needs_lpips = pytest.mark.skipif(
    importlib.util.find_spec("lpips") is None, reason="the lpips package (pip install --no-deps lpips) is not installed"
)


def _reference_lpips(network: str, trunk_path, monkeypatch):
    """The lpips package's LPIPS with its trunk replaced by our weights."""
    trunk_name = {"vgg": "vgg16", "alex": "alexnet"}[network]
    trunk = load_trunk(trunk_name, trunk_path)
    models = types.SimpleNamespace(**{trunk_name: lambda **_: types.SimpleNamespace(features=trunk.features)})
    fake = types.ModuleType("torchvision")
    fake.models = models
    monkeypatch.setitem(sys.modules, "torchvision", fake)
    monkeypatch.setitem(sys.modules, "torchvision.models", models)
    if importlib.util.find_spec("tqdm") is None:
        monkeypatch.setitem(sys.modules, "tqdm", types.SimpleNamespace(tqdm=lambda x, **_: x))
    for name in [m for m in sys.modules if m == "lpips" or m.startswith("lpips.")]:
        monkeypatch.delitem(sys.modules, name)
    package = importlib.import_module("lpips")
    return package.LPIPS(net=network, pretrained=True, pnet_rand=True, verbose=False).eval()


@needs_lpips
@pytest.mark.parametrize("network, trunk", [("vgg", "vgg16"), ("alex", "alexnet")])
def test_matches_the_reference_implementation(tmp_path, monkeypatch, network, trunk):
    path = tmp_path / f"{trunk}.pth"
    save_random_trunk(trunk, path, seed=1)
    ours = LPIPS(network, path)
    reference = _reference_lpips(network, path, monkeypatch)
    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(3, 3, 64, 80, generator=g), torch.rand(3, 3, 64, 80, generator=g)
    with torch.no_grad():
        expected = reference(a * 2 - 1, b * 2 - 1).reshape(-1)
        torch.testing.assert_close(ours(a, b), expected, rtol=1e-4, atol=1e-6)
    assert ours(a, a).abs().max() < 1e-6 and (ours(a, b) > 0).all()
    torch.testing.assert_close(ours(a, b), ours(b, a), rtol=1e-5, atol=1e-7)


@needs_lpips
def test_linear_weights_come_from_the_installed_package():
    path = packaged_linear_weights("vgg")
    assert path.name == "vgg.pth" and path.parent.name == "v0.1"


def test_clear_errors(tmp_path, monkeypatch):
    save_random_trunk("vgg16", tmp_path / "vgg16.pth")
    with pytest.raises(InputError, match="LPIPS network 'squeeze'"):
        LPIPS("squeeze", tmp_path / "vgg16.pth")
    monkeypatch.setattr(lpips_module.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(InputError, match="pip install --no-deps lpips"):
        packaged_linear_weights("vgg")
    torch.save({"lin0.model.1.weight": torch.zeros(1, 3, 1, 1)}, tmp_path / "bad.pth")
    with pytest.raises(InputError, match=r"lin0.model.1.weight has shape \(1, 3, 1, 1\), expected \(1, 64, 1, 1\)"):
        LPIPS("vgg", tmp_path / "vgg16.pth", tmp_path / "bad.pth")
