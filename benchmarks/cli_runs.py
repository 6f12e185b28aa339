"""Running the `lumos3d` command from benchmark scripts: any subcommand, and `eval` on LOM buu
reduced to the numbers the tables need."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

from report import SHARED_DATA

REPO = Path(__file__).resolve().parents[1]
SHARED = SHARED_DATA
LOM = SHARED / "lom"
LUMOS3D = str(Path(sys.executable).with_name("lumos3d"))


def run_lumos3d(arguments: list[str]) -> tuple[str, float]:
    """stdout and wall seconds of `lumos3d ARGUMENTS --quiet`; RuntimeError with stderr on failure."""
    started = time.perf_counter()
    result = subprocess.run([LUMOS3D, *arguments, "--quiet"], capture_output=True, text=True, env=os.environ)
    if result.returncode != 0:
        raise RuntimeError(f"lumos3d {' '.join(arguments)} failed:\n{result.stderr}")
    return result.stdout, time.perf_counter() - started


def run_lumos3d_json(arguments: list[str]) -> tuple[dict, float]:
    """The `--json` summary and wall seconds of `lumos3d ARGUMENTS`."""
    stdout, seconds = run_lumos3d([*arguments, "--json"])
    return json.loads(stdout), seconds


def evaluate_buu(mode: str, options: list[str], folder: str) -> dict[str, tuple[dict, dict, dict]]:
    """protocol -> (our mean row, the gamma mean row, camera accuracy) of `lumos3d eval` on buu."""
    scores = {}
    for protocol in ("context", "holdout"):
        report, _ = run_lumos3d_json(
            ["eval", str(LOM), "--scenes", "buu", "--mode", mode, "--protocol", protocol, "--out", f"{folder}-{protocol}",
             *options]
        )
        ours = next(r for r in report["rows"] if r["scene"] == "mean" and r["method"] == "lumos3d")
        gamma = next(r for r in report["rows"] if r["scene"] == "mean" and r["method"] == "gamma")
        scores[protocol] = (ours, gamma, report["cameras"]["buu"])
    return scores
