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
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import machine_description, markdown_table, median_seconds, peak_rss_mib, write_section  # noqa: E402

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


def measure(count: int, size: int, backend: str, repeats: int) -> dict:
    """Median forward and backward milliseconds and the process's peak RSS."""
    gaussians, cameras = synthetic_scene(count, size)
    baseline = peak_rss_mib()
    forward = median_seconds(lambda: render(gaussians, cameras, backend=backend), repeats=repeats)
    backward_times = []
    for _ in range(repeats + 1):
        _, loss = _forward_backward(gaussians, cameras, backend)
        start = time.perf_counter()
        loss.backward()
        backward_times.append(time.perf_counter() - start)
    backward = sorted(backward_times[1:])[len(backward_times[1:]) // 2]
    with torch.no_grad():
        output = render(gaussians, cameras, backend=backend)
    return {
        "gaussians": count, "size": size, "backend": backend,
        "forward_ms": 1000 * forward, "backward_ms": 1000 * backward,
        "peak_rss_mib": peak_rss_mib(), "baseline_rss_mib": baseline,
        "visible": int(output.visible.sum()), "coverage": float(output.alphas.mean()),
    }


def _child(arguments: list[str], environment: dict | None = None) -> dict:
    command = [sys.executable, __file__, *arguments]
    result = subprocess.run(command, capture_output=True, text=True, env=environment, check=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


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


GUIDE_GAP = (
    "The issue's guide for 200k Gaussians at 512² is ≤ 100 ms forward and ≤ 300 ms backward on these "
    "2 cores; forward is about 3× over it. The scene covers every pixel with ~55 Gaussians on "
    "average (~14 M pixel-Gaussian evaluations per image), and each costs one scalar `exp` "
    "(~12 ns here: numba gets no vectorised SVML `exp` on this machine because Intel's `icc_rt` "
    "does not load with numba 0.68), so the compositing loop alone is ~170 ms of the forward pass. "
    "GPU parity with gsplat is not yet checked: this project's machine has no GPU."
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller sweep; do not update docs")
    parser.add_argument("--measure", nargs=3, metavar=("COUNT", "SIZE", "BACKEND"), help=argparse.SUPPRESS)
    parser.add_argument("--first-call", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    if args.first_call:
        print(json.dumps(first_call()))
        return
    if args.measure:
        count, size, backend = int(args.measure[0]), int(args.measure[1]), args.measure[2]
        print(json.dumps(measure(count, size, backend, args.repeats)))
        return

    repeats = str(2 if args.quick else args.repeats)
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
    for count, size in sweep:
        result = _child(["--measure", str(count), str(size), "cpu", "--repeats", repeats])
        sweep_rows.append([
            f"{count:,}", f"{size}²", f"{result['forward_ms']:.1f}", f"{result['backward_ms']:.1f}",
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
        markdown_table(["Gaussians", "image", "forward ms", "backward ms", "peak RSS MiB", "drawn", "mean alpha"], sweep_rows),
        GUIDE_GAP,
    ])
    print(text)
    if not args.quick:
        write_section("rasterizer", text)


if __name__ == "__main__":
    main()
