"""The output commit with many files (io/output_set.py): a render of N frames written into a new
folder, then again into the same folder (the re-run checks every earlier frame against the
folder's manifest, hashes it, moves it out of the way, checks it again where it was moved, and
moves the new one in), for this working tree and, in the same run, a baseline revision (its
`src/` taken with `git archive`). Each measurement in a fresh process and a fresh folder; the
frames are random bytes of a PNG's size at 320x240. Writes a table into docs/performance.md.

    .venv/bin/python benchmarks/commit.py                        # against the revision before the fix
    .venv/bin/python benchmarks/commit.py --frames 100 500 --no-doc
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
from io import BytesIO
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import markdown_table, table_section, write_section  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
# The last revision whose ownership check read the folder's manifest once for every file it judged.
BEFORE_ONE_READ = "bf69cdc"
FRAME_BYTES = 150_000  # an 8-bit PNG of a 320x240 render, about

# The child: `render`'s output set of N frames committed twice into one folder, each timed.
_CHILD = """
import json, os, sys, time
from pathlib import Path
from lumos3d_cli.io.output_set import OutputSet
folder, count, size = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
names = [f"{index:05d}.png" for index in range(count)]
payload = os.urandom(size)
def commit():
    outputs = OutputSet(folder, "render", "render")
    for name in names:
        outputs.add_file(name)
    started = time.perf_counter()
    with outputs.staged() as staging:
        for name in names:
            (staging.root / name).write_bytes(payload)
    return time.perf_counter() - started
print(json.dumps({"first_s": commit(), "again_s": commit()}))
"""


def _extract_sources(revision: str, folder: Path) -> Path:
    """`src/` of `revision` under `folder` (read with `git archive`; the work tree is untouched)."""
    archive = subprocess.run(["git", "archive", revision, "src"], cwd=REPO, capture_output=True, check=True).stdout
    with tarfile.open(fileobj=BytesIO(archive)) as tar:
        tar.extractall(folder, filter="data")
    return folder / "src"


def _commit_seconds(source: Path, frames: int, scratch: Path) -> dict:
    """{first_s, again_s} of `frames` frames committed twice, lumos3d_cli imported from `source`."""
    with tempfile.TemporaryDirectory(dir=scratch) as folder:
        done = subprocess.run([sys.executable, "-c", _CHILD, str(Path(folder) / "frames"), str(frames), str(FRAME_BYTES)],
                              env={**os.environ, "PYTHONPATH": str(source)}, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"the commit of {frames} frames failed (from {source}): {done.stderr.strip()[-500:]}")
    return json.loads(done.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default=BEFORE_ONE_READ, help="the revision to compare with")
    parser.add_argument("--frames", type=int, nargs="+", default=[100, 500, 1000, 2000])
    parser.add_argument("--no-doc", action="store_true", help="print only")
    args = parser.parse_args()
    if any(count < 1 for count in args.frames):
        parser.error("--frames: give counts of 1 or more")
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        baseline = _extract_sources(args.baseline, Path(folder))
        for count in args.frames:
            before, after = (_commit_seconds(source, count, Path(folder)) for source in (baseline, REPO / "src"))
            rows.append({"frames": count, "before": before, "after": after})
            print(rows[-1], flush=True)
    table = markdown_table(
        ["frames", f"first, {args.baseline} s", "first, now s", f"again, {args.baseline} s", "again, now s"],
        [[row["frames"], f"{row['before']['first_s']:.2f}", f"{row['after']['first_s']:.2f}",
          f"{row['before']['again_s']:.2f}", f"{row['after']['again_s']:.2f}"] for row in rows])
    text = table_section(
        "## Committing many outputs (`benchmarks/commit.py`)",
        f"A render's output set of N frames ({FRAME_BYTES // 1000} kB each, random bytes) committed into a new "
        "folder (first), then again into the same folder (again: every earlier frame checked against the manifest, "
        "hashed, moved out of the way and checked again where it was moved), each in a fresh process; "
        f"{args.baseline} (its `src/`) against this tree. Before, the ownership check read the folder's manifest "
        "once for every file it judged, so a re-run grew with the square of the frames.",
        table)
    print(text)
    if not args.no_doc:
        write_section("commit", text)


if __name__ == "__main__":
    main()
