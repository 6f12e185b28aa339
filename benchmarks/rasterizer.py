"""Rasterizer speed: forward/backward time and peak memory of the CPU kernel on a fixed synthetic
scene, a sweep over Gaussian count and image size, the ratio to the dense pure-torch twin
measured in the same run, and the numba JIT compile / cache-load time.

    .venv/bin/python benchmarks/rasterizer.py            # full run, rewrites docs/performance.md
    .venv/bin/python benchmarks/rasterizer.py --quick    # smaller sweep, no doc update

Each configuration runs in a fresh child process so that its peak RSS is its own.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import machine_description, markdown_table, peak_rss_mib, run_child, write_section  # noqa: E402

from lumos3d_cli.io.cameras import Cameras, make_intrinsics  # noqa: E402
from lumos3d_cli.io.gaussians import Gaussians  # noqa: E402
from lumos3d_cli.render.render import render  # noqa: E402


def synthetic_scene(count: int, size: int, sh_degree: int = 3, seed: int = 0) -> tuple[Gaussians, Cameras]:
    """`count` Gaussians spread over the view of a size x size camera (64 degree field of view)
    at depths 2-8, anisotropic with projected standard deviations around 1.5 px (log-normal),
    opacities U(0.05, 1), SH degree 3. Dense like a trained 3DGS scene: every pixel is covered."""
    g = torch.Generator().manual_seed(seed)
    focal = 0.8 * size
    depth = 2 + 6 * torch.rand(count, generator=g)
    u = (torch.rand(count, generator=g) * 1.2 - 0.1) * size
    v = (torch.rand(count, generator=g) * 1.2 - 0.1) * size
    means = torch.stack([(u - size / 2) / focal * depth, (v - size / 2) / focal * depth, depth], dim=1)
    scales = torch.exp(torch.randn(count, 3, generator=g) * 0.5 + torch.log(1.5 * depth / focal)[:, None])
    sh = torch.randn(count, (sh_degree + 1) ** 2, 3, generator=g) * 0.1
    sh[:, 0] *= 3
    gaussians = Gaussians(means, torch.randn(count, 4, generator=g), scales, 0.05 + 0.95 * torch.rand(count, generator=g), sh)
    cameras = Cameras(torch.eye(4, dtype=torch.float64)[:3][None], make_intrinsics(focal, focal, size / 2, size / 2), [(size, size)])
    return gaussians, cameras


def _forward_backward(gaussians: Gaussians, cameras: Cameras, backend: str):
    leaves = Gaussians(**{name: t.clone().requires_grad_(True) for name, t in gaussians.tensors().items()})
    output = render(leaves, cameras, backend=backend)
    return output, (output.images.sum() + output.depths.sum())


def _median(values: list[float]) -> float:
    # the mean of the middle two for an even count: the upper one favoured ours against the
    # twin's two runs (always its slower one)
    return statistics.median(values)


def measure(count: int, size: int, backend: str, repeats: int) -> dict:
    """Median forward and backward milliseconds, wall and CPU (process time summed over threads,
    which other processes on the cores do not inflate the way they inflate wall time), and the
    process's peak RSS."""
    gaussians, cameras = synthetic_scene(count, size)
    baseline = peak_rss_mib()
    render(gaussians, cameras, backend=backend)  # warm-up: compile or load the kernels
    forward_wall, forward_cpu = [], []
    for _ in range(repeats):
        wall, cpu = time.perf_counter(), time.process_time()
        render(gaussians, cameras, backend=backend)
        forward_wall.append(time.perf_counter() - wall)
        forward_cpu.append(time.process_time() - cpu)
    backward_wall, backward_cpu = [], []
    for _ in range(repeats + 1):
        _, loss = _forward_backward(gaussians, cameras, backend)
        wall, cpu = time.perf_counter(), time.process_time()
        loss.backward()
        backward_wall.append(time.perf_counter() - wall)
        backward_cpu.append(time.process_time() - cpu)
    with torch.no_grad():
        output = render(gaussians, cameras, backend=backend)
    return {
        "gaussians": count, "size": size, "backend": backend,
        "forward_ms": 1000 * _median(forward_wall), "backward_ms": 1000 * _median(backward_wall[1:]),
        "forward_cpu_ms": 1000 * _median(forward_cpu), "backward_cpu_ms": 1000 * _median(backward_cpu[1:]),
        "peak_rss_mib": peak_rss_mib(), "baseline_rss_mib": baseline,
        "visible": int(output.visible.sum()), "coverage": float(output.alphas.mean()),
    }


def _child(arguments: list[str], environment: dict | None = None) -> dict:
    command = [sys.executable, __file__, *arguments]
    return json.loads(run_child(command, environment).strip().splitlines()[-1])


def compile_times() -> dict:
    """Cold JIT compile (empty cache dir) and warm cache load, each in a fresh process."""
    with tempfile.TemporaryDirectory() as cache:
        environment = {**os.environ, "NUMBA_CACHE_DIR": cache}
        cold = _child(["--first-call"], environment)
        warm = _child(["--first-call"], environment)
    return {"cold_s": cold["first_call_s"], "warm_s": warm["first_call_s"], "steady_s": warm["steady_s"]}


def first_call() -> dict:
    """Time of the first forward+backward (compiles or loads the kernels) vs a later one."""
    gaussians, cameras = synthetic_scene(1000, 64)
    start = time.perf_counter()
    _forward_backward(gaussians, cameras, "cpu")[1].backward()
    first = time.perf_counter() - start
    start = time.perf_counter()
    _forward_backward(gaussians, cameras, "cpu")[1].backward()
    return {"first_call_s": first, "steady_s": time.perf_counter() - start}


def guide_gap(forward_ms: float, backward_ms: float, loads: tuple[float, float]) -> str:
    """The paragraph after the sweep: this run's 200k-at-512² row against the issue's guide, what
    the compositing kernels do, and the machine's load (other processes share these cores)."""
    return (
        "The issue's guide for 200k Gaussians at 512² is ≤ 100 ms forward and ≤ 300 ms backward on "
        f"these 2 cores; this run measured {forward_ms:.0f} ms and {backward_ms:.0f} ms (forward = the "
        "whole `render()`: input checks, projection, binning, compositing, background). The scene covers "
        "every pixel with ~55 Gaussians (~25 M pixel-Gaussian box evaluations per image). Compositing "
        "runs one branch-free SIMD pass over the 16 columns of a tile row per Gaussian and row of its "
        "box, in the inputs' precision (float32 here), with a polynomial `exp` (numba has no vector "
        "`exp` on this machine: no SVML) and the tile's per-pixel state in one array so that LLVM "
        "needs no overlap checks per row; binning sorts the drawn Gaussians once instead of every "
        "tile's entries, by a stable radix sort on every core (`kernels/radix_sort.py`: 763k Gaussians "
        "26 -> 10 ms against numpy's sort, same order), and the projection builds each 2D covariance as "
        "one 2x3 product (763k Gaussians 54 -> 39 ms). Before/after the SIMD compositing, measured interleaved (3 fresh processes each, "
        "the old kernels from a copy of the tree, load average 4–5): 200k/512² forward 749 → 436 ms, "
        "backward 1046 → 488 ms; 50k/512² forward 376 → 220 ms, backward 315 → 123 ms (the compositing "
        "kernel alone, float32, 1 thread's CPU: forward 300 → 78 ms, backward 550 → 175 ms). "
        "Load average (1 min) at the start and end of this run: "
        f"{loads[0]:.1f}, {loads[1]:.1f} — with other processes on the 2 cores, wall times above "
        "are inflated by up to several times; compare rows of one run only. "
        "GPU parity with gsplat is tested by `tests/render/test_gsplat_parity.py` where CUDA and gsplat exist; "
        "this machine has no GPU."
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller sweep; do not update docs")
    parser.add_argument("--measure", nargs=3, metavar=("COUNT", "SIZE", "BACKEND"), help=argparse.SUPPRESS)
    parser.add_argument("--first-call", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats {args.repeats}: give at least 1")
    if args.first_call:
        print(json.dumps(first_call()))
        return
    if args.measure:
        count, size, backend = int(args.measure[0]), int(args.measure[1]), args.measure[2]
        print(json.dumps(measure(count, size, backend, args.repeats)))
        return

    repeats = str(2 if args.quick else args.repeats)
    load_at_start = os.getloadavg()[0]
    compile_info = compile_times()
    print(f"JIT: cold compile {compile_info['cold_s']:.1f} s, cache load {compile_info['warm_s']:.2f} s, "
          f"steady call {1000 * compile_info['steady_s']:.1f} ms")

    twin_configs = [(1000, 64), (2000, 128)] if args.quick else [(1000, 64), (2000, 128), (5000, 128)]
    twin_rows = []
    for count, size in twin_configs:
        ours = _child(["--measure", str(count), str(size), "cpu", "--repeats", repeats])
        twin = _child(["--measure", str(count), str(size), "reference", "--repeats", "2"])
        twin_rows.append([
            f"{count:,}", f"{size}²", f"{ours['forward_ms']:.2f}", f"{twin['forward_ms']:.0f}",
            f"**{twin['forward_ms'] / ours['forward_ms']:.0f}×**", f"{ours['backward_ms']:.2f}",
            f"{twin['backward_ms']:.0f}", f"**{twin['backward_ms'] / ours['backward_ms']:.0f}×**",
            f"{ours['peak_rss_mib'] - ours['baseline_rss_mib']:.0f}", f"{twin['peak_rss_mib'] - twin['baseline_rss_mib']:.0f}",
        ])
        print("twin", twin_rows[-1])

    if args.quick:
        sweep = [(50_000, 256), (200_000, 512)]
    else:
        sweep = [(200_000, 512), (10_000, 512), (50_000, 512), (1_000_000, 512), (200_000, 256), (200_000, 1024)]
    sweep_rows = []
    guide_row = None
    for count, size in sweep:
        result = _child(["--measure", str(count), str(size), "cpu", "--repeats", repeats])
        if (count, size) == (200_000, 512):
            guide_row = result
        sweep_rows.append([
            f"{count:,}", f"{size}²", f"{result['forward_ms']:.1f}", f"{result['backward_ms']:.1f}",
            f"{result['forward_cpu_ms']:.0f}", f"{result['backward_cpu_ms']:.0f}",
            f"{result['peak_rss_mib']:.0f}", f"{result['visible']:,}", f"{result['coverage']:.3f}",
        ])
        print("sweep", sweep_rows[-1])

    text = "\n\n".join([
        "## Rasterizer (CPU, numba)",
        f"Machine: {machine_description()}. Script: `benchmarks/rasterizer.py`. Scene: "
        "`synthetic_scene` (Gaussians spread over a 64° view at depths 2–8, projected standard "
        "deviations ≈ 1.5 px, opacities U(0.05, 1), SH degree 3; every pixel is covered). "
        "Forward = `render()`; backward = gradients of image + depth sums w.r.t. all Gaussian "
        "parameters. Medians of repeated runs; each row in a fresh process.",
        f"JIT: first call with an empty cache {compile_info['cold_s']:.1f} s (compiling float32 "
        f"kernels), first call with the cache warm {compile_info['warm_s']:.2f} s, a later call "
        f"{1000 * compile_info['steady_s']:.1f} ms (1k Gaussians, 64²). The cache lives in "
        "`__pycache__` beside the kernels (`cache=True`).",
        "### Against the dense pure-torch twin (same run)",
        "The twin (`render/reference.py`) holds [pixels × Gaussians] tensors, so the comparison "
        "uses scenes it can hold. Targets: ≥ 50× forward, ≥ 20× backward.",
        markdown_table(
            ["Gaussians", "image", "ours fwd ms", "twin fwd ms", "fwd ratio", "ours bwd ms", "twin bwd ms",
             "bwd ratio", "ours peak MiB (Δ)", "twin peak MiB (Δ)"], twin_rows),
        "### Sweep (SH degree 3)",
        markdown_table(
            ["Gaussians", "image", "forward ms", "backward ms", "forward CPU ms", "backward CPU ms", "peak RSS MiB",
             "drawn", "mean alpha"], sweep_rows),
        guide_gap(guide_row["forward_ms"], guide_row["backward_ms"], (load_at_start, os.getloadavg()[0])),
    ])
    print(text)
    if not args.quick:
        write_section("rasterizer", text)


if __name__ == "__main__":
    main()
