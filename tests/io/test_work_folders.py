"""io/work_folders.py: a job's private temporary folders, and those that killed runs left."""

import os
import subprocess
import sys
import tempfile

from lumos3d_cli.io import atomic
from lumos3d_cli.io.work_folders import work_folder


def _dead_pid() -> int:
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def test_the_folders_of_killed_runs_are_removed_by_the_next_and_no_other(tmp_path, monkeypatch):
    """A SIGKILL while structure-from-motion ran left lumos3d-sfm-* (about 1-14 MB) in /tmp for good."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    host, started = atomic._HOST, atomic._start_time(os.getpid())
    killed = tmp_path / f"lumos3d-sfm-{_dead_pid()}-{host}-123.k2j3h4g5"
    running = tmp_path / f"lumos3d-sfm-{os.getpid()}-{host}-{started}.a1b2c3d4"  # a live run's (here: this process)
    # a killed run whose process id a live process has taken since (in a container every run is process 1)
    reused = tmp_path / f"lumos3d-sfm-{os.getpid()}-{host}-{int(started) - 1}.b1b2c3d4"
    elsewhere = tmp_path / f"lumos3d-sfm-{_dead_pid()}-{'0' * 8 if host != '0' * 8 else '1' * 8}-5.e5f6g7h8"
    users = tmp_path / "lumos3d-sfm-notes"  # not of lumos3d's naming
    for folder in (killed, running, reused, elsewhere, users):
        (folder / "images").mkdir(parents=True)
    with work_folder("lumos3d-sfm-") as work:
        assert work.is_dir() and work.name.startswith(f"lumos3d-sfm-{os.getpid()}-{host}-{started}.")
        assert not killed.exists() and not reused.exists()
        assert running.is_dir() and elsewhere.is_dir() and users.is_dir()
    assert not work.exists()
