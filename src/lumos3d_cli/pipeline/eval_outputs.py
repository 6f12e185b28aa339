"""What `lumos3d eval` writes: its report folder's files. Needs no torch, so that the command
refuses a bad output folder before the libraries load."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from lumos3d_cli.io.output_set import OutputSet


def eval_outputs(out: Path | str, scenes: Sequence[str], inputs: Sequence[Path | str | None] = ()) -> OutputSet:
    """The report's files in `out` (metrics.json, metrics.csv, a contact sheet per scene; the
    sheets of scenes an earlier report had and this one has not go), kept clear of `inputs`."""
    outputs = OutputSet(Path(out), "eval", "eval", inputs, parameter="out").add_file("metrics.json").add_file("metrics.csv")
    for scene in scenes:
        outputs.add_file(f"contact_sheet_{scene}.png")
    return outputs
