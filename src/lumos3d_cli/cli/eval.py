"""`lumos3d eval`: the paper's protocol on LOM-layout scenes, with PSNR/SSIM/LPIPS and a blind
gamma baseline row in every report, plus the accuracy of the predicted cameras against the
scene's transforms files."""

from __future__ import annotations

import csv
import io
import json
import time
from pathlib import Path

import numpy as np
import typer
from rich.table import Table

from lumos3d_cli.cli.console import print_json, progress_bar, stdout_console
from lumos3d_cli.data.degradations import MODES
from lumos3d_cli.data.lom import find_lom_scenes
from lumos3d_cli.errors import InputError
from lumos3d_cli.eval.contact_sheet import contact_sheet
from lumos3d_cli.io.atomic import atomic_directory
from lumos3d_cli.io.image_write import write_image
from lumos3d_cli.pipeline.lom_eval import PROTOCOLS, evaluate_lom_scene
from lumos3d_cli.pipeline.presets import DEFAULT_RESTORE_PRESET, get_restore_preset
from lumos3d_cli.pipeline.quality import QualityMeter, mean_metrics
from lumos3d_cli.pipeline.restore import file_sha256, load_restoration_model, resolve_checkpoint

EXAMPLES = """
  lumos3d eval ../shared/data/lom --scenes buu
  lumos3d eval LOM/ --scenes bike,buu,chair,sofa --mode over-exposure --protocol holdout --out report/
  lumos3d eval LOM/ --checkpoint run/final.safetensors --lpips-weights vgg16-397923af.pth --json
"""


def _cell(value: float | None, digits: int) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def eval_command(
    root: Path = typer.Argument(..., help="A LOM-layout folder (scenes with high/, low/ or over_exp/, transforms_test.json)."),
    scenes: str | None = typer.Option(None, "--scenes", help="Comma-separated scene names (default: all found)."),
    mode: str = typer.Option("low-light", "--mode", help=f"One of: {', '.join(MODES)}."),
    protocol: str = typer.Option("context", "--protocol", help="context or holdout."),
    checkpoint: Path | None = typer.Option(None, "--checkpoint", help="Model weights (default: the bundled model of --mode)."),
    preset: str = typer.Option(DEFAULT_RESTORE_PRESET, "--preset", help="fast, balanced or best."),
    max_views: int | None = typer.Option(None, "--max-views", help="Views per scene through the network (default: the preset's)."),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    out: Path = typer.Option(Path("report"), "--out", help="Report folder (metrics.json, metrics.csv, contact sheets)."),
    baseline: str = typer.Option("gamma", "--baseline", help="gamma (blind auto-gamma row) or none."),
    lpips_weights: Path | None = typer.Option(None, "--lpips-weights", help="torchvision vgg16 weights for LPIPS."),
    json_output: bool = typer.Option(False, "--json", help="Print metrics.json on stdout."),
) -> None:
    """Evaluate restoration on LOM scenes (PSNR on [0,1], SSIM 11x11 sigma 1.5, LPIPS)."""
    if mode not in MODES:
        raise InputError(f"--mode {mode!r}: use one of {', '.join(MODES)}")
    if protocol not in PROTOCOLS:
        raise InputError(f"--protocol {protocol!r}: use one of {', '.join(PROTOCOLS)}")
    if baseline not in ("gamma", "none"):
        raise InputError(f"--baseline {baseline!r}: use gamma or none")
    settings = get_restore_preset(preset)
    limit = max_views or settings.max_views
    names = [n.strip() for n in scenes.split(",") if n.strip()] if scenes else None
    found = find_lom_scenes(root, mode, names)
    weights = resolve_checkpoint(checkpoint, mode)
    meter = QualityMeter.create(lpips_weights)
    model = load_restoration_model(weights, device)
    results = []
    with progress_bar() as progress:
        task = progress.add_task(f"eval ({protocol})", total=len(found))
        for scene in found:
            results.append(evaluate_lom_scene(scene, model, settings, protocol, limit, meter))
            progress.advance(task)
    rows = []
    for result in results:
        rows.append({"scene": result.scene, "method": "lumos3d", **mean_metrics(result.ours), "seconds": result.seconds})
        if baseline == "gamma":
            rows.append({"scene": result.scene, "method": "gamma", **mean_metrics(result.baseline), "seconds": None})
    methods = ["lumos3d"] + (["gamma"] if baseline == "gamma" else [])
    for method in methods:
        per_scene = [r for r in rows if r["method"] == method]
        mean = {k: (sum(r[k] for r in per_scene) / len(per_scene) if all(r[k] is not None for r in per_scene) else None)
                for k in ("psnr", "ssim", "lpips", "seconds")}
        rows.append({"scene": "mean", "method": method, **mean})
    report = {
        "root": str(root), "mode": mode, "protocol": protocol, "preset": settings.name, "max_views": limit,
        "checkpoint": {"name": weights.name, "sha256": file_sha256(weights)}, "lpips": meter.lpips_note,
        "rows": rows,
        "frames": {r.scene: {"test": r.test_frames, "views_used": r.views_used, "lumos3d": r.ours, "gamma": r.baseline}
                   for r in results},
        "cameras": {r.scene: r.pose.as_dict() for r in results if r.pose is not None},
    }
    with atomic_directory(out) as staging:
        (staging / "metrics.json").write_text(json.dumps(report, indent=2) + "\n")
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=["scene", "method", "psnr", "ssim", "lpips", "seconds"])
        writer.writeheader()
        writer.writerows(rows)
        (staging / "metrics.csv").write_text(buffer.getvalue())
        for result in results:
            sheet_rows = []
            for index, frame in enumerate(result.test_frames):
                ours, base = result.ours[index], result.baseline[index]
                row = [(result.inputs[index], f"{result.scene} {frame} input ({mode})"),
                       (result.renders[index], f"lumos3d  {ours['psnr']:.2f} dB  {ours['ssim']:.3f}")]
                if baseline == "gamma":
                    row.append((result.baseline_images[index], f"gamma  {base['psnr']:.2f} dB  {base['ssim']:.3f}"))
                row.append((result.references[index], "ground truth (high)"))
                sheet_rows.append(row)
            write_image(staging / f"contact_sheet_{result.scene}.png", contact_sheet(sheet_rows).astype(np.float32) / 255)
    if json_output:
        print_json(report)
        return
    table = Table(title=f"LOM {mode}, protocol {protocol}, preset {settings.name} ({meter.lpips_note})")
    for column in ("scene", "method", "PSNR ↑", "SSIM ↑", "LPIPS ↓", "time s"):
        table.add_column(column, justify="left" if column in ("scene", "method") else "right")
    for row in rows:
        table.add_row(row["scene"], row["method"], _cell(row["psnr"], 2), _cell(row["ssim"], 3), _cell(row["lpips"], 3),
                      _cell(row["seconds"], 1), end_section=row["scene"] == "mean" and row["method"] == methods[-1])
    stdout_console().print(table)
    for result in results:
        if result.pose is not None:
            pose = result.pose
            stdout_console().print(
                f"{result.scene} cameras ({result.views_used} views, {pose.pairs} pairs): rotation error median "
                f"{pose.rotation_error_median:.1f}°, translation direction {pose.translation_error_median:.1f}°, "
                f"RRA@15 {pose.rra_15:.2f}, RTA@15 {pose.rta_15:.2f}, AUC@30 {pose.auc_30:.3f}"
            )
    stdout_console().print(f"report: {out}/metrics.json, {out}/metrics.csv, contact sheets in {out}/")
