"""The log files of a training run: metrics.jsonl (one line per logged step), validation.jsonl
(written by train/validation.py) and, optionally, TensorBoard scalars. A resumed run first drops
the lines of the work it is about to redo, so the logs read like those of an uninterrupted run."""

from __future__ import annotations

import json
from pathlib import Path

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import write_bytes_atomic
from lumos3d_cli.io.json_text import finite_document


class RunLogs:
    """The logs in the run folder `output`; `tensorboard` adds scalars under output/tensorboard."""

    def __init__(self, output: Path, tensorboard: bool):
        self.output = output
        self._tensorboard = None
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter
            except ImportError as error:
                raise InputError("tensorboard: true needs the tensorboard package (pip install tensorboard)") from error
            self._tensorboard = SummaryWriter(str(output / "tensorboard"))

    def append_step(self, step: int, learning_rate: float, skipped: bool, seconds: float, nonfinite_total: int,
                    terms: dict[str, float]) -> None:
        """One metrics.jsonl line (and TensorBoard scalars) for a step."""
        line = {"step": step, "lr": learning_rate, "skipped": skipped, "seconds": round(seconds, 4),
                "nonfinite_total": nonfinite_total, **terms}
        # a skipped step's non-finite loss is null (strict JSON; "skipped" says why), as in every file we write
        with open(self.output / "metrics.jsonl", "a") as handle:
            handle.write(json.dumps(finite_document(line), allow_nan=False) + "\n")
        if self._tensorboard is not None:
            for name, value in terms.items():
                self._tensorboard.add_scalar(f"loss/{name}", value, step)
            self._tensorboard.add_scalar("lr", learning_rate, step)

    def truncate(self, start: int) -> None:
        """Drop the log lines of the work about to be redone from step `start`: metrics.jsonl
        lines of steps >= start, validation.jsonl lines after `start` steps (its step counts the
        steps done before it, so the validation at `start` itself is kept)."""
        for name, last_kept in (("metrics.jsonl", start - 1), ("validation.jsonl", start)):
            path = self.output / name
            if path.is_file():
                kept = [line for line in path.read_text().splitlines() if line and json.loads(line)["step"] <= last_kept]
                write_bytes_atomic(path, ("\n".join(kept) + "\n" if kept else "").encode())

    def validated_steps(self) -> set[int]:
        """The steps validation.jsonl has a validation after."""
        path = self.output / "validation.jsonl"
        if not path.is_file():
            return set()
        return {int(json.loads(line)["step"]) for line in path.read_text().splitlines() if line}

    def close(self) -> None:
        if self._tensorboard is not None:
            self._tensorboard.close()
