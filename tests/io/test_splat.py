import numpy as np
import pytest
import torch

from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.io.splat import write_splat

from factories import random_gaussians

C0 = 0.28209479177387814  # docs/formats.md: rgb = 0.5 + C0 * f_dc


def test_splat_layout_and_values(tmp_path):
    gaussians = Gaussians(
        means=torch.tensor([[1.0, 2.0, 3.0], [-1.0, 0.0, 0.5]]),
        quats=torch.tensor([[2.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]]),
        scales=torch.tensor([[0.1, 0.1, 0.1], [1.0, 2.0, 3.0]]),
        opacities=torch.tensor([1.0, 0.5]),
        sh=torch.tensor([[[0.0, 0.0, 0.0]], [[1.0, -1.0, 10.0]]]),
    )
    write_splat(tmp_path / "a.splat", gaussians)
    data = (tmp_path / "a.splat").read_bytes()
    assert len(data) == 2 * 32
    # The larger, more opaque-by-volume Gaussian comes first.
    first = data[:32]
    np.testing.assert_array_equal(np.frombuffer(first[:12], "<f4"), [-1.0, 0.0, 0.5])
    np.testing.assert_array_equal(np.frombuffer(first[12:24], "<f4"), [1.0, 2.0, 3.0])
    rgba = np.frombuffer(first[24:28], np.uint8)
    expected_rgb = np.clip(np.round((0.5 + C0 * np.array([1.0, -1.0, 10.0])) * 255), 0, 255)
    np.testing.assert_array_equal(rgba, [*expected_rgb, 128])
    np.testing.assert_array_equal(np.frombuffer(first[28:32], np.uint8), [255, 128, 128, 128])  # zero quat -> identity
    second = data[32:]
    np.testing.assert_array_equal(np.frombuffer(second[24:28], np.uint8), [128, 128, 128, 255])
    np.testing.assert_array_equal(np.frombuffer(second[28:32], np.uint8), [255, 128, 128, 128])


def test_values_that_are_not_activated_are_refused_as_by_write_ply(tmp_path):
    """A scale of -1 and an opacity of 2 were written to the .splat as they were (alpha 255)."""
    for name, value in (("scales", -1.0), ("opacities", 2.0)):
        gaussians = random_gaussians(3, 0)
        getattr(gaussians, name).view(-1)[0] = value
        with pytest.raises(ValueError, match=rf"scene to export\.{name}: 1 value\(s\) outside the activated range"):
            write_splat(tmp_path / "a.splat", gaussians)
    assert not (tmp_path / "a.splat").exists()
