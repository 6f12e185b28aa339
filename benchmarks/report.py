"""Shared helpers for the benchmark scripts: machine description, timing, peak memory, and
writing one section of a document (docs/performance.md unless told) between markers (each script
owns its section)."""

from __future__ import annotations

import json
import os
import platform
import re
import resource
import statistics
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import torch

PERFORMANCE_DOC = Path(__file__).resolve().parents[1] / "docs" / "performance.md"
# The shared data, where the tests find it too (README: LUMOS3D_SHARED_DATA), by default beside the repository.
SHARED_DATA = Path(os.environ.get("LUMOS3D_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))

_HEADER = """# Performance

Measured by the scripts in `benchmarks/`; each script rewrites its own section below. Ratios
are against a reference measured in the same run. Times are medians of repeated runs after
warm-up.
"""


def run_child(command: list[str], environment: dict | None = None) -> str:
    """stdout of a measuring child process; on failure, exit naming the command with the end of
    its stderr (a CalledProcessError said only "returned non-zero exit status 1")."""
    result = subprocess.run(command, capture_output=True, text=True, env=environment)
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed (exit {result.returncode}):\n{result.stderr[-3000:]}")
    return result.stdout


def machine_description() -> str:
    """One line naming CPU model, core count, torch threads and GPU (if any)."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no GPU"
    return f"{cpu}, {os.cpu_count()} cores, torch {torch.__version__} with {torch.get_num_threads()} threads, {gpu}"


def median_seconds(function: Callable[[], object], repeats: int = 5, warmup: int = 1) -> float:
    """Median wall time of `function()` over `repeats` runs after `warmup` runs."""
    for _ in range(warmup):
        function()
    times = []
    for _ in range(repeats):
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        start = time.perf_counter()
        function()
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def peak_rss_mib() -> float:
    """Peak resident set size of this process so far, in MiB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def markdown_table(header: list[str], rows: list[list[object]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return "\n".join(lines)


def table_section(heading: str, description: str, table: str) -> str:
    """A measured section: the heading, what was measured and how, the table, and the machine."""
    return "\n".join([heading, "", description, "", table, "", f"Machine: {machine_description()}."])


def check_result_file(path: Path | None) -> str | None:
    """Why `path` cannot take a benchmark's JSON results (None: it can): checked before the run,
    not after it (a run of minutes lost to a missing folder), and never over a file that is not
    a JSON document, such as a photo given by mistake (which was replaced)."""
    if path is None:
        return None
    if path.is_dir():
        return f"{path}: is a folder; give a .json file"
    if path.suffix.lower() != ".json":
        return f"{path}: give a .json file"
    if path.exists():
        try:
            json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, ValueError):
            return f"{path}: exists and is not a JSON document of results; give another path"
    return None


def write_section(name: str, markdown: str, document: Path = PERFORMANCE_DOC) -> None:
    """Replace (or append) the section `name` of `document`."""
    begin, end = f"<!-- {name}:begin -->", f"<!-- {name}:end -->"
    if document.exists():
        text = document.read_text()
    else:
        text = _HEADER if document == PERFORMANCE_DOC else ""
    block = f"{begin}\n{markdown.strip()}\n{end}"
    pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end), re.S)
    text = pattern.sub(lambda _: block, text) if pattern.search(text) else text.rstrip() + "\n\n" + block + "\n"
    document.parent.mkdir(parents=True, exist_ok=True)
    document.write_text(text)
