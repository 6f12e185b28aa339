"""Run the real `lumos3d` command in a child process: for exit codes, signals and what a run
leaves on disk, which an in-process call cannot show."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from lumos3d_cli.io.manifest import MANIFEST_NAME

# One thread per child: the machine running the tests is shared.
_ENV = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}


@dataclass
class ProcessResult:
    code: int
    out: str
    err: str

    @property
    def last_line(self) -> str:
        lines = self.err.strip().splitlines()
        return lines[-1] if lines else ""


def command(*args) -> list[str]:
    return [sys.executable, "-m", "lumos3d_cli", *(str(a) for a in args)]


def run_lumos3d(*args, timeout: float = 600, cwd: Path | None = None) -> ProcessResult:
    """`lumos3d ARGS...` to its end."""
    done = subprocess.run(command(*args), capture_output=True, text=True, timeout=timeout, env=_ENV, cwd=cwd)
    return ProcessResult(done.returncode, done.stdout, done.stderr)


def interrupt_when(args, ready: Callable[[subprocess.Popen], bool], signum: int, timeout: float = 600,
                   poll: float = 0.01, cwd: Path | None = None, env: dict[str, str] | None = None) -> ProcessResult:
    """Start `lumos3d ARGS...` (with `env` added to the environment), send `signum` as soon as
    `ready(process)` holds, and wait for the end. Fails when the command ends before it was ready
    (the signal would test nothing)."""
    process = subprocess.Popen(command(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env={**_ENV, **(env or {})}, cwd=cwd)
    try:
        deadline = time.monotonic() + timeout
        while not ready(process):
            if process.poll() is not None:
                out, err = process.communicate()
                raise AssertionError(f"the command ended (code {process.returncode}) before it was ready to interrupt:\n{err[-3000:]}")
            if time.monotonic() > deadline:
                raise AssertionError("the command did not become ready to interrupt in time")
            time.sleep(poll)
        process.send_signal(signum)
        out, err = process.communicate(timeout=timeout)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    return ProcessResult(process.returncode, out, err)


def cli_started(process: subprocess.Popen) -> bool:
    """True once the child catches SIGHUP (Linux /proc): the CLI entry has installed its signal
    handlers, so the command is running. (Python catches SIGINT from the start and pycolmap's
    logging library SIGTERM on import; nothing but the CLI catches SIGHUP.)"""
    try:
        status = Path(f"/proc/{process.pid}/status").read_text()
    except OSError:
        return False
    caught = next(int(line.split()[1], 16) for line in status.splitlines() if line.startswith("SigCgt:"))
    return bool(caught & (1 << (signal.SIGHUP - 1)))


def hidden_entries(folder: Path) -> list[Path]:
    """Hidden files and folders anywhere under `folder` (where temporaries live), but for the
    manifests of what lumos3d wrote (io/manifest.py)."""
    return sorted(p for p in folder.rglob(".*") if p.name != MANIFEST_NAME)


def expected_exit(signum: int) -> int:
    return 128 + signum


def signal_name(signum: int) -> str:
    return signal.Signals(signum).name
