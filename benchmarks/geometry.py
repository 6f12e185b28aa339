"""Where the cameras come from, measured on LOM buu: `lumos3d eval --geometry network|sfm` (camera
accuracy against buu's transforms, PSNR/SSIM under both protocols, seconds) in both modes, and the
wall time of `lumos3d restore` of all 25 low-light photos with each source (default preset), with
its stages from summary.json.

    .venv/bin/python benchmarks/geometry.py   # rewrites the "geometry" section of docs/performance.md
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cli_runs import LOM, evaluate_buu, run_lumos3d_json  # noqa: E402
from report import machine_description, markdown_table, write_section  # noqa: E402

from lumos3d_cli.pipeline.presets import get_restore_preset  # noqa: E402

SOURCES = ("network", "sfm")
STAGES = ("load_model", "sfm", "network", "fuse", "budget", "refine", "render", "write")  # summary.json's seconds


def _evaluation_rows(folder: Path) -> list[list[object]]:
    rows = []
    for mode in ("low-light", "over-exposure"):
        for source in SOURCES:
            scores = evaluate_buu(mode, ["--geometry", source], str(folder / f"eval-{mode}-{source}"))
            (context, gamma, cameras), (holdout, _, _) = scores["context"], scores["holdout"]
            rows.append([
                mode, source, f"{cameras['auc_30']:.3f}", f"{cameras['rotation_error_median']:.2f}",
                f"{cameras['translation_error_median']:.2f}",
                f"{context['psnr']:.2f} / {context['ssim']:.3f}", f"{holdout['psnr']:.2f} / {holdout['ssim']:.3f}",
                f"{gamma['psnr']:.2f} / {gamma['ssim']:.3f}", f"{context['seconds']:.1f}",
            ])
    return rows


def _restore_rows(folder: Path) -> list[list[object]]:
    rows = []
    for source in SOURCES:
        summary, wall = run_lumos3d_json(
            ["restore", str(LOM / "buu" / "low"), "-o", str(folder / f"restore-{source}" / "scene.ply"), "--geometry", source]
        )
        seconds = summary["seconds"]
        geometry = summary["geometry"]
        rows.append([
            source, len(summary["views"]), f"{wall:.1f}", *(f"{seconds.get(stage, 0.0):.1f}" for stage in STAGES),
            geometry.get("depth_consistency") if geometry.get("depth_consistency") is not None else "—",
            f"{summary['peak_rss_mib']:.0f}",
        ])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--no-doc", action="store_true", help="print the tables only; leave docs/performance.md")
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        evaluation = _evaluation_rows(folder)
        restore = _restore_rows(folder)
    views = get_restore_preset("balanced").max_views
    load = f"load average {load_before:.1f} at the start, {os.getloadavg()[0]:.1f} at the end"
    markdown = "\n".join([
        "## Geometry sources (LOM buu)",
        "",
        f"Machine: {machine_description()}; {load} (seconds are only comparable at a load near 0). "
        "Script: `benchmarks/geometry.py`. Bundled models, default preset "
        f"(`balanced`: up to {views} views through the network). Camera accuracy over all view pairs the source "
        "placed (network: the views it saw; sfm: all 25) against buu's transforms.",
        "",
        markdown_table(
            ["mode", "geometry", "camera AUC@30", "rotation error ° (median)", "translation direction ° (median)",
             "context PSNR / SSIM", "holdout PSNR / SSIM", "gamma PSNR / SSIM", "eval s (context)"],
            evaluation,
        ),
        "",
        "`lumos3d restore` of the 25 low-light photos (wall time from the command's start; stages from summary.json):",
        "",
        markdown_table(
            ["geometry", "views restored", "wall s", *(f"{stage} s" for stage in STAGES), "depth consistency",
             "peak RSS MiB"],
            restore,
        ),
    ])
    print(markdown)
    if not args.no_doc:
        write_section("geometry", markdown)


if __name__ == "__main__":
    main()
