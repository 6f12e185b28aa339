"""Speed and memory of the Lumos3D network (random weights): forward time, peak resident memory and
achieved FLOP rate over 1-32 views at each architecture's resolution, in float32 and under bf16
autocast, against a matrix multiply measured in the same run; plus a training step of `tiny`.
Writes the "model" section of docs/performance.md.

    python benchmarks/model.py                                  # tiny and vggt-1b, 60-minute budget
    python benchmarks/model.py --architectures tiny --budget-minutes 3
    python benchmarks/model.py --max-views 4 --cell-limit-seconds 120
    python benchmarks/model.py --json r.json; python benchmarks/model.py --retry r.json   # redo contended cells

Every cell runs in its own process, so its peak RSS is its own. A cell whose estimated time
(FLOPs / the rate achieved by the previous cell) exceeds the per-cell limit or the remaining
budget is not run; the table then shows the FLOP-based estimate instead.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import torch
from torch.utils.flop_counter import FlopCounterMode

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import check_result_file, machine_description, markdown_table, median_seconds, peak_rss_mib, write_section  # noqa: E402

from lumos3d_cli.model.architectures import get_architecture  # noqa: E402
from lumos3d_cli.model.lumos3d import Lumos3D, build_model  # noqa: E402

VIEWS = (1, 2, 4, 8, 16, 32)
PRECISIONS = ("fp32", "bf16")
MATMUL_SIZE = 2048
# Rate assumed for the first cell of a series, as a fraction of the matmul rate.
FIRST_CELL_EFFICIENCY = 0.5
# A cell waits (up to --max-wait-seconds) until other processes use less than this fraction of
# the CPUs; a cell whose own process got less than SHARE_WARNING of its threads' time is flagged.
IDLE_THRESHOLD = 0.1
SHARE_WARNING = 0.85


def network_flops(architecture_name: str, views: int) -> int:
    """FLOPs of one forward pass of the aggregator and heads for `views` square images at the
    architecture's size, counted on the meta device (shapes only; the voxelizer is not included)."""
    architecture = get_architecture(architecture_name)
    size = architecture.image_size
    with torch.device("meta"):
        model = Lumos3D(architecture).requires_grad_(False)
        images = torch.rand(1, views, 3, size, size)
    with FlopCounterMode(display=False) as counter:
        tokens = model.aggregator(images, model.token_layers)
        model.camera_head(tokens[architecture.depth - 1])
        model.depth_head(tokens, images)
        model.gaussian_head(tokens, images)
    return counter.get_total_flops()


def matmul_gflops(dtype: torch.dtype) -> float:
    """GFLOP/s of a square matrix multiply of MATMUL_SIZE in `dtype`."""
    a, b = torch.randn(MATMUL_SIZE, MATMUL_SIZE, dtype=dtype), torch.randn(MATMUL_SIZE, MATMUL_SIZE, dtype=dtype)
    return 2 * MATMUL_SIZE**3 / median_seconds(lambda: a @ b, repeats=5, warmup=2) / 1e9


def cpu_busy_fraction(window: float = 1.0) -> float:
    """Fraction of all CPUs' time spent busy over `window` seconds (Linux /proc/stat); measured
    while this process sleeps, so it is the load of other processes."""

    def sample() -> tuple[int, int]:
        fields = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
        idle = fields[3] + fields[4]  # idle + iowait
        return sum(fields) - idle, sum(fields)

    busy0, total0 = sample()
    time.sleep(window)
    busy1, total1 = sample()
    return (busy1 - busy0) / max(total1 - total0, 1)


def wait_for_idle(max_wait: float) -> float:
    """Wait until other processes leave the CPUs (nearly) idle, at most `max_wait` seconds;
    returns the last busy fraction seen."""
    deadline = time.monotonic() + max_wait
    busy = cpu_busy_fraction()
    while busy >= IDLE_THRESHOLD and time.monotonic() < deadline:
        time.sleep(5)
        busy = cpu_busy_fraction()
    return busy


def _timed(function, repeats: int, warmup: int) -> tuple[float, float]:
    """(median seconds, share of this process's threads' CPU time it actually got)."""
    cpu, wall = time.process_time(), time.perf_counter()
    seconds = median_seconds(function, repeats=repeats, warmup=warmup)
    share = (time.process_time() - cpu) / (time.perf_counter() - wall) / torch.get_num_threads()
    return seconds, min(share, 1.0)


def run_cell(architecture_name: str, views: int, precision: str, repeats: int) -> dict:
    """(In a child process.) Time the full forward pass, voxelizer included, and a matmul of the
    same precision just before it (the reference for the achieved rate)."""
    matmul = matmul_gflops(torch.float32 if precision == "fp32" else torch.bfloat16)
    start = time.perf_counter()
    model = build_model(architecture_name, seed=0).eval()
    build_seconds = time.perf_counter() - start
    size = model.architecture.image_size
    images = torch.rand(1, views, 3, size, size, generator=torch.Generator().manual_seed(0))

    def forward() -> None:
        with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=precision == "bf16"):
            model(images)

    seconds, share = _timed(forward, repeats, 1 if repeats > 1 else 0)
    return {
        "seconds": seconds, "peak_rss_mib": peak_rss_mib(), "build_seconds": build_seconds,
        "matmul_gflops": matmul, "cpu_share": share,
    }


def training_step(views: int, repeats: int) -> dict:
    """(In a child process.) One optimisation step of `tiny` at its resolution: forward, a loss
    on every output (a stand-in for the rendering losses; rendering is not timed here),
    backward and AdamW."""
    model = build_model("tiny", seed=0).train()
    optimizer = torch.optim.AdamW(model.parameters(), lr=2e-4)
    size = model.architecture.image_size
    images = torch.rand(1, views, 3, size, size, generator=torch.Generator().manual_seed(0))

    def step() -> None:
        output = model(images)
        loss = sum(e.square().mean() for e in output.pose_enc_list) + output.depth.mean()
        loss = loss + sum(t.square().mean() for t in output.gaussians[0].tensors().values())
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    seconds, share = _timed(step, repeats, 1)
    return {"seconds": seconds, "peak_rss_mib": peak_rss_mib(), "cpu_share": share}


def _child(arguments: list[str], timeout: float) -> dict:
    command = [sys.executable, __file__, *arguments]
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return {"skipped": f"timed out after {timeout:.0f} s"}
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        return {"skipped": f"failed: {last}"}
    return json.loads(done.stdout.strip().splitlines()[-1])


def _fmt_seconds(value: float) -> str:
    return f"{value:.3g}"


def _dagger(cell: dict) -> str:
    return f" † (CPU share {100 * cell['cpu_share']:.0f} %)" if cell["cpu_share"] < SHARE_WARNING else ""


def measure(args: argparse.Namespace) -> dict:
    deadline = time.monotonic() + 60 * args.budget_minutes
    rates = {precision: matmul_gflops(torch.float32 if precision == "fp32" else torch.bfloat16) for precision in PRECISIONS}
    results: dict = {"matmul_gflops": rates, "architectures": {}, "training": {}}
    for architecture_name in args.architectures:
        architecture = get_architecture(architecture_name)
        flops = {views: network_flops(architecture_name, views) for views in VIEWS}
        with torch.device("meta"):
            parameters = sum(p.numel() for p in Lumos3D(architecture).parameters())
        cells = {}
        # GFLOP/s expected for the next cell of each precision; views-major order, so that both
        # precisions are measured at the small view counts before the budget runs out
        rate = {precision: FIRST_CELL_EFFICIENCY * rates[precision] for precision in PRECISIONS}
        for views in VIEWS:
            for precision in PRECISIONS:
                estimate = flops[views] / (rate[precision] * 1e9)
                allowed = min(args.cell_limit_seconds, deadline - time.monotonic())
                if views > args.max_views:
                    cell = {"skipped": f"above --max-views {args.max_views}"}
                elif estimate > allowed:
                    cell = {"skipped": f"estimate above the {'per-cell limit' if allowed == args.cell_limit_seconds else 'remaining budget'}"}
                else:
                    # the warm-up and repeated runs only where they fit; else a single cold run
                    repeats = args.repeats if estimate * (1 + args.repeats) <= allowed else 1
                    busy = wait_for_idle(args.max_wait_seconds)
                    cell = _child(
                        ["--cell", architecture_name, str(views), precision, str(repeats)],
                        timeout=max(120.0, 3 * estimate * (1 + repeats) + 120),
                    )
                    cell["runs"] = repeats
                    cell["busy_before"] = busy
                if "seconds" in cell:
                    rate[precision] = flops[views] / cell["seconds"] / 1e9
                    cell["gflops_per_s"] = rate[precision]
                cell["estimated_seconds"] = estimate
                cell["flops"] = flops[views]
                cells[f"{precision}/{views}"] = cell
                print(f"{architecture_name} {precision} {views} views: {cell}", file=sys.stderr, flush=True)
        results["architectures"][architecture_name] = {"parameters": parameters, "image_size": architecture.image_size, "cells": cells}
    if "tiny" in args.architectures:
        for views in (2, 4):
            wait_for_idle(args.max_wait_seconds)
            results["training"][views] = _child(["--train", str(views), str(args.repeats)], timeout=600)
    return results


def retry_contended(results: dict, args: argparse.Namespace) -> dict:
    """Run again every measured cell whose process got too little CPU (†), after waiting for an
    idle machine; keep whichever run got the larger CPU share."""
    for architecture_name, entry in results["architectures"].items():
        for key, cell in entry["cells"].items():
            if "seconds" not in cell or cell["cpu_share"] >= SHARE_WARNING:
                continue
            precision, views = key.split("/")
            wait_for_idle(args.max_wait_seconds)
            timeout = max(120.0, 3 * cell["seconds"] * (1 + cell["runs"]) + 120)
            again = _child(["--cell", architecture_name, views, precision, str(cell["runs"])], timeout=timeout)
            print(f"retry {architecture_name} {key}: {again}", file=sys.stderr, flush=True)
            if again.get("cpu_share", 0.0) > cell["cpu_share"]:
                again.update(runs=cell["runs"], flops=cell["flops"], estimated_seconds=cell["estimated_seconds"])
                again["gflops_per_s"] = cell["flops"] / again["seconds"] / 1e9
                entry["cells"][key] = again
    for views, cell in results["training"].items():
        if "seconds" in cell and cell["cpu_share"] < SHARE_WARNING:
            wait_for_idle(args.max_wait_seconds)
            again = _child(["--train", str(views), str(args.repeats)], timeout=600)
            if again.get("cpu_share", 0.0) > cell["cpu_share"]:
                results["training"][views] = again
    return results


def render(results: dict, args: argparse.Namespace) -> str:
    rates = results["matmul_gflops"]
    lines = [
        "## Model forward pass (`benchmarks/model.py`)",
        "",
        f"Machine: {machine_description()}.",
        "",
        f"Matrix multiply ({MATMUL_SIZE}x{MATMUL_SIZE}) at the start of the run: {rates['fp32']:.1f} GFLOP/s (fp32), "
        f"{rates['bf16']:.1f} GFLOP/s (bf16). Random weights, square images at each architecture's resolution, batch 1, "
        f"median of {args.repeats} timed runs after one warm-up, or a single cold run where only one fits the limits. "
        "Time covers the whole forward pass (backbone, heads, unprojection, voxel fusion, pruning). GFLOP/s counts the "
        "FLOPs of the backbone and heads (counted on the meta device; the voxelizer's few FLOPs are left out) over that "
        "time; the percentage compares it with the same-precision matmul measured in the cell's own process just before "
        "it. Peak RSS is that of that fresh process (weights included). Each cell waits for other processes to leave the "
        f"CPUs idle (up to {args.max_wait_seconds:.0f} s); a dagger (†) marks a cell whose process got less than "
        f"{100 * SHARE_WARNING:.0f} % of its {torch.get_num_threads()} threads' CPU time (the machine is shared), so its "
        "time is inflated. Cells marked *not measured* show the estimate FLOPs / rate of the previous cell, and why.",
    ]
    for architecture_name, entry in results["architectures"].items():
        lines += ["", f"### `{architecture_name}` ({entry['parameters'] / 1e6:.1f} M parameters, {entry['image_size']} px)", ""]
        header = ["views", "TFLOP"]
        for precision in PRECISIONS:
            header += [f"{precision} time (s)", f"{precision} peak RSS (MiB)", f"{precision} GFLOP/s (% matmul)"]
        rows = []
        for views in VIEWS:
            row: list[object] = [views, f"{entry['cells'][f'fp32/{views}']['flops'] / 1e12:.3g}"]
            for precision in PRECISIONS:
                cell = entry["cells"][f"{precision}/{views}"]
                if "seconds" in cell:
                    notes = (" (1 cold run)" if cell["runs"] == 1 and args.repeats > 1 else "") + _dagger(cell)
                    row += [
                        _fmt_seconds(cell["seconds"]) + notes, f"{cell['peak_rss_mib']:.0f}",
                        f"{cell['gflops_per_s']:.1f} ({100 * cell['gflops_per_s'] / cell['matmul_gflops']:.0f} %)",
                    ]
                else:
                    row += [f"not measured ({cell['skipped']}); est. {_fmt_seconds(cell['estimated_seconds'])}", "-", "-"]
            rows.append(row)
        lines.append(markdown_table(header, rows))
    if results["training"]:
        lines += [
            "",
            f"### `tiny` training step ({get_architecture('tiny').image_size} px)",
            "",
            "Forward, a loss on every output (stand-in for the rendering losses, whose rasterizer time is not "
            "included), backward and AdamW, fp32.",
            "",
        ]
        rows = []
        for views, cell in results["training"].items():
            if "seconds" in cell:
                rows.append([views, _fmt_seconds(cell["seconds"]) + _dagger(cell), f"{cell['peak_rss_mib']:.0f}"])
            else:
                rows.append([views, cell["skipped"], "-"])
        lines.append(markdown_table(["views", "step time (s)", "peak RSS (MiB)"], rows))
    return "\n".join(lines)


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--cell":
        architecture_name, views, precision, repeats = sys.argv[2], int(sys.argv[3]), sys.argv[4], int(sys.argv[5])
        print(json.dumps(run_cell(architecture_name, views, precision, repeats)))
        return 0
    if len(sys.argv) > 1 and sys.argv[1] == "--train":
        print(json.dumps(training_step(int(sys.argv[2]), int(sys.argv[3]))))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--architectures", nargs="+", default=["tiny", "vggt-1b"])
    parser.add_argument("--budget-minutes", type=float, default=60.0, help="total time for the forward cells")
    parser.add_argument("--cell-limit-seconds", type=float, default=600.0, help="skip cells estimated to take longer")
    parser.add_argument("--max-views", type=int, default=32)
    parser.add_argument("--max-wait-seconds", type=float, default=900.0, help="longest wait for other load to end before a cell")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per cell (after one warm-up)")
    parser.add_argument("--json", type=Path, help="also write the raw results here")
    parser.add_argument("--render", type=Path, metavar="JSON", help="measure nothing; render the results of an earlier --json")
    parser.add_argument("--retry", type=Path, metavar="JSON", help="re-measure the contended (†) cells of an earlier --json")
    parser.add_argument("--no-write", action="store_true", help="print the section instead of writing docs/performance.md")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats {args.repeats}: give at least 1")
    if (refusal := check_result_file(args.json)) is not None:
        parser.error(f"--json {refusal}")
    if args.render:
        results = json.loads(args.render.read_text())
    elif args.retry:
        results = retry_contended(json.loads(args.retry.read_text()), args)
        args.retry.write_text(json.dumps(results, indent=2) + "\n")
    else:
        results = measure(args)
        if args.json:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(results, indent=2) + "\n")
    section = render(results, args)
    if args.no_write:
        print(section)
    else:
        write_section("model", section)
    return 0


if __name__ == "__main__":
    sys.exit(main())
