"""`lumos3d train`: train the teacher or the student from a YAML config (one process, or many
under torchrun)."""

from __future__ import annotations

import logging
import os
import signal
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from lumos3d_cli.cli.console import print_json, progress_bar, say, state
from lumos3d_cli.cli.interrupts import library_imports
from lumos3d_cli.errors import InputError, Interrupted
from lumos3d_cli.train.run_folder import check_run_folder, earlier_run, numbered_folder, other_outputs, read_run

if TYPE_CHECKING:
    from lumos3d_cli.train.trainer import StepReport, TrainResult

EXAMPLES = """
  lumos3d train configs/tiny-cpu.yaml
  lumos3d train configs/low-light.yaml optim.steps=2000 output=runs/ll
  lumos3d train configs/low-light.yaml --resume
  lumos3d train configs/low-light.yaml --new-run          [dim]# output holds a run: start in output-2[/dim]
  torchrun --nproc_per_node 8 -m lumos3d_cli train configs/vggt-1b-gpu.yaml
"""

_SHOWN_TERMS = ("total", "mse", "pose", "depth", "distill_pose", "distill_depth", "image", "content", "voxel", "lpips")


def _describe(report: StepReport) -> str:
    shown = [f"{name} {report.terms[name]:.4g}" for name in _SHOWN_TERMS if name in report.terms]
    return "  ".join(shown) + ("  [skipped]" if report.skipped else "")


def train_command(
    config: Path = typer.Argument(..., help="Training config (YAML)."),
    overrides: list[str] = typer.Argument(None, help="key=value overrides, e.g. optim.lr=1e-4 data.views=6."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run in the output folder from its latest checkpoint."),
    new_run: bool = typer.Option(False, "--new-run", help="If the output folder holds another run, start in the next free numbered folder beside it (output-2, ...)."),
    max_steps: int | None = typer.Option(None, "--max-steps", help="Stop (with a checkpoint) after this many steps in total."),
    json_output: bool = typer.Option(False, "--json", help="Print a JSON summary on stdout (rank 0)."),
) -> None:
    """Train a model: the normal-light teacher or the low-light/over-exposure student.

    Stopped by SIGINT, SIGTERM or SIGHUP, it saves a checkpoint after the current step and exits
    with 128 + the signal number (130, 143, 129), so that a scheduler sees an unfinished run."""
    # Training imports torch, the network, the losses and the data (seconds): imported here, when
    # the command runs, so that `--help` stays fast.
    with library_imports():
        from lumos3d_cli.train.config import load_config, training_inputs
        from lumos3d_cli.train.distributed import setup_distributed, shutdown_distributed
        from lumos3d_cli.train.trainer import Trainer, check_max_steps
    if os.environ.get("RANK", "0") != "0":  # under torchrun only rank 0 speaks (progress, notes); errors still show
        state.quiet = True
    check_max_steps(max_steps)
    if resume and new_run:
        raise InputError("--resume continues the run in the output folder and --new-run starts another: give one")
    settings = load_config(config, overrides or [])
    output = Path(settings.output)
    held = (earlier_run(output) or other_outputs(output)) if new_run else None
    if held is not None:
        output = numbered_folder(output)
        say(f"{settings.output} holds {held}; this run starts in {output}")
        settings = replace(settings, output=str(output))
    check_run_folder(output, training_inputs(settings, config), resume)
    if resume:
        run = read_run(output)
        say(f"resuming {run.describe() if run is not None else 'the run'} in {output}")
    context = setup_distributed(settings.device)
    if not context.is_main:
        logging.getLogger("lumos3d_cli").setLevel(logging.ERROR)
    try:
        with progress_bar() as progress:
            task = progress.add_task(f"train ({settings.stage})", total=settings.optim.steps)

            def on_step(report: StepReport) -> None:
                if context.is_main:
                    progress.update(task, completed=report.step + 1, description=f"train {_describe(report)}")

            def on_resume(step: int, folder: Path) -> None:
                progress.update(task, completed=step)
                if context.is_main:
                    say(f"resuming from step {step} ({folder})")

            trainer = Trainer(settings, context, on_step if not state.quiet else None, on_resume)
            result = trainer.run(resume=resume, max_steps=max_steps, config_file=config)
    finally:
        shutdown_distributed()
    if not context.is_main:  # rank 0 says where the checkpoint is; the others end with the same code, silently
        if result.stop_signal is not None:
            raise typer.Exit(128 + result.stop_signal)
        return
    last = result.history[-1] if result.history else None
    summary = {
        "stage": settings.stage, "output": settings.output, "steps_done": result.steps_done,
        "stopped_early": result.stopped_early, "stop_signal": _signal_name(result.stop_signal),
        "final_checkpoint": str(result.final_checkpoint) if result.final_checkpoint else None,
        "selected_checkpoint": str(result.selected_checkpoint) if result.selected_checkpoint else None,
        "last_terms": last.terms if last else {}, "skipped_steps": result.skipped_steps, "world_size": context.world_size,
        "seconds_per_step": round(sum(r.seconds for r in result.history) / max(1, len(result.history)), 4),
    }
    if json_output:
        print_json(summary)
    else:
        skipped = f" ({result.skipped_steps} skipped for a non-finite loss or gradient)" if result.skipped_steps else ""
        say(f"{settings.stage}: {result.steps_done} steps done{skipped}; checkpoints in {settings.output}/checkpoints"
            + (f"; final weights {result.final_checkpoint}" if result.final_checkpoint else "")
            + (f"; selected by {settings.select}: {result.selected_checkpoint}" if result.selected_checkpoint else ""))
    _stop_if_interrupted(result)


def _signal_name(signum: int | None) -> str | None:
    return signal.Signals(signum).name if signum is not None else None


def _stop_if_interrupted(result: TrainResult) -> None:
    """A run a signal stopped ends as interrupted (exit 128 + signal) once its checkpoint is saved."""
    if result.stop_signal is not None:
        saved = f"checkpoint {result.last_checkpoint} saved" if result.last_checkpoint else "checkpoint saved"
        raise Interrupted(result.stop_signal, f"stopped after step {result.steps_done}; {saved}; continue with --resume")
