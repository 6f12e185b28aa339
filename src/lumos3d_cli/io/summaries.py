"""Plain-dict summaries of scene, camera and image files (for `lumos3d info`)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from lumos3d_cli.io.camera_files import find_camera_source, read_cameras
from lumos3d_cli.io.colmap import is_colmap_model
from lumos3d_cli.io.images import probe_image
from lumos3d_cli.io.ply import ply_fields_to_gaussians, read_ply_fields, unusable_values, usable_rows


def _stats(values: np.ndarray) -> dict[str, float | None]:
    """min, median, mean and max of the finite values; None for each when there are none (an
    empty scene: `info --json` must stay valid JSON, which has no NaN)."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return {"min": None, "median": None, "mean": None, "max": None}
    return {
        "min": float(finite.min()), "median": float(np.median(finite)),
        "mean": float(finite.mean()), "max": float(finite.max()),
    }


def summarize_gaussian_file(path: Path | str) -> dict:
    """Count, SH degree, bounds, opacity/scale statistics and non-finite count of a `.ply`."""
    path = Path(path)
    fields, degree = read_ply_fields(path)
    non_finite = sum(unusable_values(fields, degree).values())  # what `render` and `convert` refuse
    gaussians = ply_fields_to_gaussians(fields[usable_rows(fields, degree)], degree)
    means = gaussians.means.numpy()
    bounds = (
        {"min": means.min(axis=0).tolist(), "max": means.max(axis=0).tolist()} if len(means) else {"min": None, "max": None}
    )
    return {
        "kind": "gaussians",
        "path": str(path),
        "file_bytes": path.stat().st_size,
        "count": int(fields.shape[0]),
        "sh_degree": degree,
        "bounds": bounds,
        "opacity": _stats(gaussians.opacities.numpy()),
        "scale": _stats(gaussians.scales.numpy().ravel()),
        "non_finite_values": non_finite,
    }


def summarize_camera_file(path: Path | str) -> dict:
    """Views, image sizes, focal lengths, field of view and camera-centre extent."""
    source = find_camera_source(path)
    cameras = read_cameras(path)
    focal = cameras.intrinsics[:, 0, 0].double()
    widths = torch.tensor([w for w, _ in cameras.sizes], dtype=torch.float64)
    fov_x = torch.rad2deg(2 * torch.atan(widths / (2 * focal)))
    centers = cameras.centers().double()
    steps = (centers[1:] - centers[:-1]).norm(dim=1) if len(cameras) > 1 else torch.zeros(1, dtype=torch.float64)
    return {
        "kind": "cameras",
        "path": str(source),
        "format": "transforms.json" if not source.is_dir() else "colmap" if is_colmap_model(source) else "transforms splits",
        "count": len(cameras),
        "image_sizes": {f"{w}x{h}": n for (w, h), n in Counter(cameras.sizes).items()},
        "focal_px": _stats(focal.numpy()),
        "fov_x_deg": _stats(fov_x.numpy()),
        "centers_min": centers.min(dim=0).values.tolist(),
        "centers_max": centers.max(dim=0).values.tolist(),
        "mean_step_between_views": float(steps.mean()),
        "first": cameras.names[0],
        "last": cameras.names[-1],
    }


def summarize_image_files(paths: Sequence[Path]) -> dict:
    """Count, sizes, bit depths and kinds (RAW or not) from the file headers."""
    headers = [probe_image(path) for path in paths]
    return {
        "kind": "images",
        "count": len(headers),
        "sizes": {f"{w}x{h}": n for (w, h), n in Counter((h.width, h.height) for h in headers).items()},
        "bit_depths": {str(bits): n for bits, n in Counter(h.bit_depth for h in headers).items()},
        "kinds": dict(Counter(h.kind for h in headers)),
        "raw": sum(h.kind == "raw" for h in headers),
        "total_bytes": sum(path.stat().st_size for path in paths),
        "first": paths[0].name,
        "last": paths[-1].name,
    }
