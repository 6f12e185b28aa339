"""The CPU rasterizer as a torch.autograd.Function: projection, binning and compositing run in
numba kernels; the backward pass is hand-written (see kernels/). `rasterize_with_weights` is the
same forward pass without gradients that also sums each Gaussian's rendered weight."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numba
import numpy as np
import torch

from lumos3d_cli.render.kernels.binning import bin_and_sort
from lumos3d_cli.render.kernels.projection import project_backward, project_forward
from lumos3d_cli.render.kernels.rasterize import (
    GRADIENT_COLUMNS,
    gather_entry_gradients,
    rasterize_backward,
    rasterize_forward,
)
from lumos3d_cli.render.settings import RasterSettings
from lumos3d_cli.render.view_threads import kernel_threads

_CHUNKS_PER_THREAD = 8
# Below this many (Gaussians + pixels) one thread is faster than waking the others.
_SMALL_PROBLEM = 20_000


@contextmanager
def _kernel_threads(gaussians: int, pixels: int) -> Iterator[None]:
    """Run numba with this thread's kernel threads (`view_threads.kernel_threads`: torch's count,
    or 1 in a worker that renders one view of several), or one thread for problems too small to
    gain from more. The caller's counts are put back after: numba's (a render left the user's own
    numba code on one thread) and torch's (numba's OpenMP layer, started by the process's first
    call into numba's threading, sets the OpenMP count torch reads: `torch.set_num_threads(1)`
    became 2)."""
    previous_torch = torch.get_num_threads()  # read first: numba's first call starts its layer
    threads = 1 if gaussians + pixels < _SMALL_PROBLEM else kernel_threads()
    previous_numba = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        yield
    finally:
        numba.set_num_threads(previous_numba)
        if torch.get_num_threads() != previous_torch:
            torch.set_num_threads(previous_torch)


def _array(tensor: torch.Tensor) -> np.ndarray:
    return tensor.detach().contiguous().numpy()


def project(means, quats, scales, opacities, sh, viewmat, intrinsics, settings: RasterSettings) -> tuple:
    """The projection kernel on the inputs of RasterizeGaussians (CPU tensors, not differentiated).

    Returns numpy arrays in the inputs' precision: means2d [N,2], conics [N,3], depths [N],
    opacities_eff [N] (with the antialiasing compensation), colours [N,3], and radii [N,2]
    int32 (0: culled; the other outputs of a culled Gaussian are 0)."""
    numpy_dtype = np.float64 if means.dtype == torch.float64 else np.float32
    n = means.shape[0]
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    outputs = (
        np.zeros((n, 2), numpy_dtype), np.zeros((n, 3), numpy_dtype), np.zeros(n, numpy_dtype),
        np.zeros(n, numpy_dtype), np.zeros((n, 3), numpy_dtype), np.zeros((n, 2), np.int32),
    )
    project_forward(
        *(_array(t) for t in (means, quats, scales, opacities, sh)),
        np.ascontiguousarray(_array(viewmat), dtype=np.float64), fx, fy, cx, cy,
        float(settings.width), float(settings.height), settings.sh_degree,
        settings.near, settings.far, settings.eps2d, settings.antialiased, *outputs,
    )
    return outputs


def composite(means, quats, scales, opacities, sh, viewmat, intrinsics, settings: RasterSettings, entry_weights: bool):
    """Projection, binning and front-to-back compositing of one camera (numpy, no gradients).

    Returns (projected, tiles, colour [H,W,3], depth [H,W], transmittance [H,W], last [H,W],
    weights): `projected` and `tiles` as `project` and `bin_and_sort` return them, the images as
    `rasterize_forward` writes them, and weights [N] float64 — each Gaussian's rendered weight,
    the sum over pixels of alpha x transmittance — when `entry_weights`, else None."""
    with _kernel_threads(means.shape[0], settings.width * settings.height):
        numpy_dtype = np.float64 if means.dtype == torch.float64 else np.float32
        width, height = settings.width, settings.height
        projected = project(means, quats, scales, opacities, sh, viewmat, intrinsics, settings)
        means2d, conics, depths, opacities_eff, colours, radii = projected
        tile_offsets, entries, tiles_x, _ = bin_and_sort(
            means2d, radii, depths, width, height, numba.get_num_threads() * _CHUNKS_PER_THREAD
        )
        colour = np.zeros((height, width, 3), numpy_dtype)
        depth = np.zeros((height, width), numpy_dtype)
        transmittance = np.ones((height, width), numpy_dtype)
        last = np.full((height, width), -1, np.int64)
        per_entry = np.zeros(entries.shape[0], np.float64) if entry_weights else None
        rasterize_forward(
            tile_offsets, entries, tiles_x, width, height, means2d, conics, opacities_eff, colours, depths, radii,
            colour, depth, transmittance, last, per_entry,
        )
        # bincount adds in entry order: the sums do not depend on thread scheduling.
        weights = np.bincount(entries, weights=per_entry, minlength=means.shape[0]) if entry_weights else None
        return projected, (tile_offsets, entries, tiles_x), colour, depth, transmittance, last, weights


def rasterize_with_weights(means, quats, scales, opacities, sh, viewmat, intrinsics, settings: RasterSettings):
    """The forward pass of RasterizeGaussians without gradients, plus each Gaussian's rendered
    weight: (colour [H,W,3], alpha [H,W], depth [H,W], radii [N,2], weights [N]) with weights
    = sum over pixels of alpha x transmittance (0: never drawn), in the inputs' dtype."""
    projected, _, colour, depth, transmittance, _, weights = composite(
        means, quats, scales, opacities, sh, viewmat, intrinsics, settings, entry_weights=True
    )
    return (
        torch.from_numpy(colour), torch.from_numpy(1.0 - transmittance), torch.from_numpy(depth),
        torch.from_numpy(projected[5]), torch.from_numpy(weights).to(means.dtype),
    )


class RasterizeGaussians(torch.autograd.Function):
    """One camera. Inputs: means [N,3], quats [N,4] wxyz, scales [N,3], opacities [N],
    sh [N,K,3]; viewmat [3,4] world->camera (float64), intrinsics (fx, fy, cx, cy).
    Outputs: colour [H,W,3] (sum of w c, no background), alpha [H,W], depth [H,W]
    (sum of w z, not normalised) and radii [N,2] int32 (0: culled, not differentiable)."""

    @staticmethod
    def forward(ctx, means, quats, scales, opacities, sh, viewmat, intrinsics, settings: RasterSettings):
        projected, tiles, colour, depth, transmittance, last, _ = composite(
            means, quats, scales, opacities, sh, viewmat, intrinsics, settings, entry_weights=False
        )
        ctx.settings = settings
        ctx.intrinsics = tuple(float(v) for v in intrinsics)
        ctx.view = np.ascontiguousarray(_array(viewmat), dtype=np.float64)
        ctx.projected = projected
        ctx.tiles = tiles
        ctx.pixels = (transmittance, last)
        ctx.save_for_backward(means, quats, scales, opacities, sh)
        radii_tensor = torch.from_numpy(projected[5])
        ctx.mark_non_differentiable(radii_tensor)
        alpha = torch.from_numpy(1.0 - transmittance)
        return torch.from_numpy(colour), alpha, torch.from_numpy(depth), radii_tensor

    @staticmethod
    def backward(ctx, v_colour, v_alpha, v_depth, _v_radii):
        means, quats, scales, opacities, sh = ctx.saved_tensors
        settings: RasterSettings = ctx.settings
        with _kernel_threads(means.shape[0], settings.width * settings.height):
            means2d, conics, depths, opacities_eff, colours, radii = ctx.projected
            tile_offsets, entries, tiles_x = ctx.tiles
            transmittance, last = ctx.pixels
            numpy_dtype = means2d.dtype
            entry_gradients = np.zeros((entries.shape[0], GRADIENT_COLUMNS), np.float64)
            rasterize_backward(
                tile_offsets, entries, tiles_x, settings.width, settings.height, means2d, conics, opacities_eff, colours,
                depths, radii, transmittance, last,
                np.ascontiguousarray(_array(v_colour), dtype=np.float64),
                np.ascontiguousarray(_array(v_alpha), dtype=np.float64),
                np.ascontiguousarray(_array(v_depth), dtype=np.float64),
                entry_gradients,
            )
            per_gaussian = np.zeros((means.shape[0], GRADIENT_COLUMNS), np.float64)
            gather_entry_gradients(entries, entry_gradients, per_gaussian)
            n = means.shape[0]
            v_means = np.zeros((n, 3), numpy_dtype)
            v_quats = np.zeros((n, 4), numpy_dtype)
            v_scales = np.zeros((n, 3), numpy_dtype)
            v_opacities = np.zeros(n, numpy_dtype)
            v_sh = np.zeros(sh.shape, numpy_dtype)
            fx, fy, cx, cy = ctx.intrinsics
            project_backward(
                _array(means), _array(quats), _array(scales), _array(opacities), _array(sh), ctx.view,
                fx, fy, cx, cy, float(settings.width), float(settings.height), settings.sh_degree,
                settings.eps2d, settings.antialiased, radii,
                # Column views of one row-major array: each Gaussian's cotangents share a cache line,
                # and no [N]-sized copies are made.
                per_gaussian[:, 0:2], per_gaussian[:, 2:5], per_gaussian[:, 9], per_gaussian[:, 5], per_gaussian[:, 6:9],
                v_means, v_quats, v_scales, v_opacities, v_sh,
            )
            return (
                torch.from_numpy(v_means), torch.from_numpy(v_quats), torch.from_numpy(v_scales),
                torch.from_numpy(v_opacities), torch.from_numpy(v_sh), None, None, None,
            )
