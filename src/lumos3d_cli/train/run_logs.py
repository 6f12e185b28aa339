"""The log files of a training run: metrics.jsonl (one line per logged step), validation.jsonl
(written by train/validation.py) and, optionally, TensorBoard scalars. A resumed run first drops
the lines of the work it is about to redo, so the logs read like those of an uninterrupted run."""

from __future__ import annotations

import json
import logging
from pathlib import Path

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import write_bytes_atomic
from lumos3d_cli.io.json_text import finite_document

logger = logging.getLogger(__name__)


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
                kept = [text for text, line in _logged_lines(path) if line["step"] <= last_kept]
                write_bytes_atomic(path, ("\n".join(kept) + "\n" if kept else "").encode())

    def validated_steps(self) -> set[int]:
        """The steps validation.jsonl has a validation after."""
        path = self.output / "validation.jsonl"
        if not path.is_file():
            return set()
        return {int(line["step"]) for _, line in _logged_lines(path)}

    def close(self) -> None:
        if self._tensorboard is not None:
            self._tensorboard.close()


def _logged_lines(path: Path) -> list[tuple[str, dict]]:
    """The lines of a log file with what they say. A last line that is not a whole entry is
    what a process killed in the middle of appending it leaves: it is dropped with a warning.
    Damage anywhere else is an InputError naming the file and the line."""
    texts = path.read_text(encoding="utf-8", errors="replace").splitlines()
    last = max((index for index, text in enumerate(texts) if text), default=-1)
    lines = []
    for index, text in enumerate(texts):
        if not text:
            continue
        try:
            line = json.loads(text)
        except json.JSONDecodeError:
            line = None
        if not (isinstance(line, dict) and isinstance(line.get("step"), int)):
            if index == last:
                logger.warning("%s: dropping its last line, which a stopped run left unfinished: %.60s", path, text)
                break
            raise InputError(f"{path}: line {index + 1} is not a log entry ({text[:60]!r}); the log is damaged: "
                             "remove or repair that line, then resume")
        lines.append((text, line))
    return lines
