"""Start-up time of the command line (issue 37: each at most 0.5 s): the wall time of
`lumos3d --version`, `--help` and every command's `--help`, each in a fresh process, the minimum
of repeated runs after a warm-up, for this working tree and, interleaved in the same run, a
baseline revision (its `src/` taken with `git archive`), with the slow-to-import libraries each
command line imports. Writes a table into docs/performance.md.

    .venv/bin/python benchmarks/startup.py                     # against the last revision without lazy imports
    .venv/bin/python benchmarks/startup.py --baseline HEAD --repeats 3 --no-doc
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import machine_description, markdown_table, write_section  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
# The last revision whose subcommand modules imported torch, pycolmap, trimesh and viser at module level.
BEFORE_LAZY_IMPORTS = "a47879c"
COMMANDS = ("restore", "eval", "train", "render", "degrade", "info", "convert", "view")
COMMAND_LINES = [("--version",), ("--help",), *((name, "--help") for name in COMMANDS)]
HEAVY = ("torch", "numpy", "pycolmap", "trimesh", "viser", "imageio_ffmpeg", "cv2", "numba", "OpenImageIO", "rawpy",
         "safetensors", "scipy", "yaml")


def _environment(source: Path) -> dict[str, str]:
    """The environment of a child that imports lumos3d_cli from `source` (a src/ folder)."""
    return {**os.environ, "PYTHONPATH": str(source)}


def _seconds(source: Path, args: tuple[str, ...]) -> float:
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "lumos3d_cli", *args], env=_environment(source),
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        raise RuntimeError(f"lumos3d {' '.join(args)} exited with {done.returncode} (from {source})")
    return seconds


def _heavy_imports(source: Path, args: tuple[str, ...]) -> list[str]:
    """The libraries of HEAVY that `lumos3d ARGS` imports."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "lumos3d_cli", *args], env=_environment(source),
                          capture_output=True, text=True)
    imported = {line.rsplit("|", 1)[1].strip().split(".")[0] for line in done.stderr.splitlines()
                if line.startswith("import time:")}
    return [name for name in HEAVY if name in imported]


def _extract_sources(revision: str, folder: Path) -> Path:
    """`src/` of `revision` under `folder` (read with `git archive`; the work tree is untouched)."""
    archive = subprocess.run(["git", "archive", revision, "src"], cwd=REPO, capture_output=True, check=True).stdout
    with tarfile.open(fileobj=BytesIO(archive)) as tar:
        tar.extractall(folder, filter="data")
    return folder / "src"


def measure(baseline: Path, repeats: int) -> list[dict]:
    """Per command line: the minimum seconds of `repeats` runs of the baseline and of this tree,
    each run of one right after the same run of the other (so that a change in the machine's load
    reaches both), and the heavy libraries each imports."""
    trees = {"before": baseline, "after": REPO / "src"}
    for source in trees.values():  # warm-up: bytecode written, files in the page cache
        for args in COMMAND_LINES:
            _seconds(source, args)
    times = {(name, args): [] for name in trees for args in COMMAND_LINES}
    for _ in range(repeats):
        for args in COMMAND_LINES:
            for name, source in trees.items():
                times[name, args].append(_seconds(source, args))
    return [{"command": "lumos3d " + " ".join(args),
             **{f"{name}_s": min(times[name, args]) for name in trees},
             **{f"{name}_imports": _heavy_imports(source, args) for name, source in trees.items()}}
            for args in COMMAND_LINES]


def _libraries(names: list[str]) -> str:
    return ", ".join(names) if names else "none of them"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default=BEFORE_LAZY_IMPORTS, help="the revision to compare with")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-doc", action="store_true", help="print only")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        baseline = _extract_sources(args.baseline, Path(folder))
        load_before = os.getloadavg()
        rows = measure(baseline, args.repeats)
        load_after = os.getloadavg()
    for row in rows:
        print(row)
    table = markdown_table(
        ["command line", f"{args.baseline} s", "now s", f"slow imports at {args.baseline}", "slow imports now"],
        [[f"`{row['command']}`", f"{row['before_s']:.2f}", f"{row['after_s']:.2f}", _libraries(row["before_imports"]),
          _libraries(row["after_imports"])] for row in rows])
    text = "\n\n".join([
        "## Start-up (`benchmarks/startup.py`)",
        f"Machine: {machine_description()}. Each command line is `python -m lumos3d_cli ...` (what the `lumos3d` "
        f"script runs) in a fresh process; its time is the minimum of {args.repeats} runs after a warm-up, the "
        f"revision {args.baseline} (its `src/`) and this tree taken in turns. The machine's load average (1 min) was "
        f"{load_before[0]:.1f} before and {load_after[0]:.1f} after the runs, on {os.cpu_count()} cores. Slow imports: "
        f"which of {', '.join(HEAVY)} the command line imports. The target is 0.5 s each. What is left is the "
        "interpreter, typer and rich (and pydantic, which typer imports to check the options of a command line "
        "that names a subcommand: 0.05-0.09 s of each `<command> --help` here).",
        table,
    ])
    print(text)
    if not args.no_doc:
        write_section("startup", text)


if __name__ == "__main__":
    main()
