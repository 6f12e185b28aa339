"""Export to the `.splat` layout of antimatter15's WebGL viewer (32 bytes per Gaussian).

Per Gaussian: position 3 x float32, scale 3 x float32 (linear), colour RGBA 4 x uint8
(rgb = 0.5 + C0 * f_dc, alpha = opacity), rotation 4 x uint8 (normalised wxyz * 128 + 128).
Sorted by decreasing volume x opacity, like the viewer's own converter. View-dependent
colour (SH degree > 0) is dropped by the format.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from lumos3d_cli.io.atomic import write_bytes_atomic
from lumos3d_cli.io.gaussians import Gaussians, sh_dc_to_rgb
from lumos3d_cli.io.output_paths import require_new_file
from lumos3d_cli.rotations import unit_quaternions

SPLAT_DTYPE = np.dtype(
    [("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rotation", "u1", 4)]
)


def gaussians_to_splat(gaussians: Gaussians) -> np.ndarray:
    """Gaussians -> structured array of SPLAT_DTYPE records in the viewer's order."""
    gaussians.require_finite("scene to export")
    gaussians.require_activated("scene to export")
    gaussians.require_float32_range("scene to export")
    g = gaussians.detach().to(device="cpu", dtype=torch.float64)
    importance = g.scales.prod(dim=1) * g.opacities
    order = torch.argsort(-importance, stable=True)
    g = g.select(order)
    rgb = sh_dc_to_rgb(g.sh[:, 0, :])
    rgba = torch.cat([rgb, g.opacities[:, None]], dim=1)
    unit = unit_quaternions(g.quats)
    records = np.zeros(len(g), dtype=SPLAT_DTYPE)
    records["position"] = g.means.numpy()
    records["scale"] = g.scales.numpy()
    records["rgba"] = np.clip(np.round(rgba.numpy() * 255), 0, 255)
    records["rotation"] = np.clip(np.round(unit.numpy() * 128 + 128), 0, 255)
    return records


def write_splat(path: Path | str, gaussians: Gaussians, overwrite: bool = False) -> None:
    """Write a `.splat` file atomically, to a new file unless `overwrite` (an existing one is an
    InputError)."""
    require_new_file(Path(path), overwrite)
    write_bytes_atomic(path, gaussians_to_splat(gaussians).tobytes())
