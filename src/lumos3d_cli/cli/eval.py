"""`lumos3d eval`: the paper's protocol on LOM-layout scenes, with PSNR/SSIM/LPIPS and a blind
gamma baseline row in every report, plus the accuracy of the cameras against the scene's
transforms files. The job is `pipeline.evaluation`; this module parses, shows and prints."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import typer
from rich.table import Table

from lumos3d_cli.cli import preset_options
from lumos3d_cli.cli.console import print_json, progress_bar, stdout_console
from lumos3d_cli.cli.interrupts import library_imports
from lumos3d_cli.data.lom_layout import lom_scene_folders, scene_name
from lumos3d_cli.data.modes import MODES
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.output_paths import check_output_path
from lumos3d_cli.pipeline.choices import DEFAULT_RESTORE_PRESET, GEOMETRY_SOURCES
from lumos3d_cli.pipeline.eval_outputs import eval_outputs

if TYPE_CHECKING:
    from lumos3d_cli.pipeline.evaluation import EvalReport

EXAMPLES = """
  lumos3d eval ../shared/data/lom --scenes buu
  lumos3d eval LOM/ --scenes bike,buu,chair,sofa --mode over-exposure --protocol holdout --out report/
  lumos3d eval LOM/ --scenes buu --geometry network
  lumos3d eval LOM/ --checkpoint run/final.safetensors --lpips-weights vgg16-397923af.pth --json
"""


def _cell(value: float | None, digits: int) -> str:
    """A score as the table shows it: n/a where metrics.json and metrics.csv hold no number (a
    score that is not finite is written there as null and an empty cell)."""
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _print_report(report: EvalReport, out: Path) -> None:
    document = report.document
    table = Table(title=f"LOM {document['mode']}, protocol {document['protocol']}, preset {document['preset']}, "
                        f"geometry {document['geometry']} ({document['lpips']})")
    for column in ("scene", "method", "PSNR ↑", "PSNR at GT mean ↑", "SSIM ↑", "sharpness (1 = ref)", "LPIPS ↓", "time s"):
        table.add_column(column, justify="left" if column in ("scene", "method") else "right")
    for row in report.rows:
        table.add_row(row["scene"], row["method"], _cell(row["psnr"], 2), _cell(row["psnr_gt_mean"], 2), _cell(row["ssim"], 3),
                      _cell(row["sharpness"], 2), _cell(row["lpips"], 3),
                      _cell(row["seconds"], 1), end_section=row["scene"] == "mean" and row["method"] == report.methods[-1])
    console = stdout_console()
    console.print(table)
    for result in report.scenes:
        source = result.geometry.get("source", "network")
        if result.pose is not None:
            pose = result.pose
            console.print(
                f"{result.scene} cameras ({source}, {pose.pairs} view pairs): rotation error "
                f"median {pose.rotation_error_median:.1f}°, translation direction {pose.translation_error_median:.1f}°, "
                f"RRA@15 {pose.rra_15:.2f}, RTA@15 {pose.rta_15:.2f}, AUC@30 {pose.auc_30:.3f}"
            )
    console.print(f"report: {out}/metrics.json, {out}/metrics.csv, contact sheets in {out}/")


def eval_command(
    root: Path = typer.Argument(..., help="A LOM-layout folder (scenes with high/, low/ or over_exp/, transforms_test.json)."),
    scenes: str | None = typer.Option(None, "--scenes", help="Comma-separated scene names (default: all found)."),
    mode: str = typer.Option("low-light", "--mode", help=f"One of: {', '.join(MODES)}."),
    protocol: str = typer.Option("context", "--protocol", help="context or holdout."),
    checkpoint: Path | None = typer.Option(None, "--checkpoint", help="Model weights (default: the bundled model of --mode)."),
    preset: str = typer.Option(DEFAULT_RESTORE_PRESET, "--preset", help="Speed/accuracy: fast, balanced or best."),
    geometry: str = typer.Option("auto", "--geometry", help=f"Cameras from: {', '.join(GEOMETRY_SOURCES)}."),
    max_views: int | None = typer.Option(None, "--max-views", help="Views per scene through the network (default: the preset's)."),
    refine_steps: int | None = preset_options.REFINE_STEPS,
    max_gaussians: int | None = preset_options.MAX_GAUSSIANS,
    gaussian_grid: float | None = preset_options.GAUSSIAN_GRID,
    exposure_prior: float | None = preset_options.EXPOSURE_PRIOR,
    exposure_key: str | None = preset_options.EXPOSURE_KEY,
    fill_unobserved: bool = preset_options.FILL_UNOBSERVED,
    densify: bool | None = preset_options.DENSIFY,
    depth_sweep: bool | None = preset_options.DEPTH_SWEEP,
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    out: Path = typer.Option(Path("report"), "--out", help="Report folder (metrics.json, metrics.csv, contact sheets)."),
    baseline: str = typer.Option("gamma", "--baseline", help="gamma (blind auto-gamma row) or none."),
    lpips_weights: Path | None = typer.Option(None, "--lpips-weights", help="torchvision vgg16 weights for LPIPS."),
    json_output: bool = typer.Option(False, "--json", help="Print metrics.json on stdout."),
) -> None:
    """Evaluate restoration on LOM scenes (PSNR on [0,1], SSIM 11x11 sigma 1.5, LPIPS)."""
    check_output_path(out, "out", folder=True)
    names = [scene_name(n) for n in scenes.split(",") if scene_name(n)] if scenes is not None else None
    if names == []:
        raise InputError(f"{scenes!r}: names no scene; name scenes separated by commas, or leave --scenes out for "
                         "every scene found", parameter="scenes")
    inputs = [root, checkpoint, lpips_weights]
    # the contact sheets' names too, so that a file of the user's in their way is refused now, not after the work
    outputs = eval_outputs(out, names if names is not None else [p.name for p in lom_scene_folders(root)], inputs)
    outputs.check()  # a refusal comes before the libraries load; checked again under the lock
    # The evaluation imports torch, pycolmap and the whole restore job (seconds): imported here,
    # when the command runs, so that `--help` and a refused command line stay fast.
    with library_imports():
        from lumos3d_cli.pipeline.evaluation import evaluate_lom, write_eval_report
    with outputs.reserved(), progress_bar() as bars:
        tasks = []  # the bar appears once every setting is checked and the scenes are found
        report = evaluate_lom(
            root, names, mode=mode, protocol=protocol, checkpoint=checkpoint, preset=preset, geometry=geometry,
            max_views=max_views, refine_steps=refine_steps, max_gaussians=max_gaussians, gaussian_grid=gaussian_grid,
            exposure_prior=exposure_prior, exposure_key=exposure_key, fill_unobserved=fill_unobserved, densify=densify, depth_sweep=depth_sweep, device=device, baseline=baseline, lpips_weights=lpips_weights,
            on_start=lambda count: tasks.append(bars.add_task(f"eval ({protocol})", total=count)),
            on_scene=lambda _: bars.advance(tasks[0]),
        )
        write_eval_report(report, out, inputs)
    if json_output:
        print_json(report.document)
        return
    _print_report(report, out)
