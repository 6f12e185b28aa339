"""io/atomic.py: a file appears whole or not at all; a killed run's temporaries are removed by the
next run, a live run's are not; a commit a killed run left half done is finished first."""

import json
import os
import subprocess
import sys

import pytest

from lumos3d_cli.errors import InputError
from lumos3d_cli.io import atomic
from lumos3d_cli.io.atomic import COMMIT_JOURNAL, atomic_path, remove_leftovers
from lumos3d_cli.io.manifest import Manifest, describe_file


def _tree(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_a_failed_block_leaves_nothing_and_removes_the_folders_it_created(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(tmp_path / "c" / "d.bin") as temporary:
            temporary.write_bytes(b"half")
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_a_file_under_a_regular_file_is_an_input_error(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match=r"cannot be created because .*/file is a file"):
        with atomic_path(tmp_path / "file" / "out" / "a.bin"):
            pass


def _dead_pid():
    child = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(child.stdout)


def test_leftovers_of_ended_processes_are_removed_live_ones_and_user_files_kept(tmp_path, monkeypatch):
    host = atomic._HOST
    dead, live = _dead_pid(), os.getppid()
    (tmp_path / f".scene.{dead}-{host}.abc123_x.tmp.ply").write_text("killed run")
    (tmp_path / f".staging.{dead}-{host}.k2j3h4g5.tmp").mkdir()
    (tmp_path / f".staging.{dead}-{host}.k2j3h4g5.tmp" / "1.png").write_text("killed run")
    kept = [
        f".scene.{live}-{host}.abc123_x.tmp.ply",  # a run still going
        f".scene.{dead}-0badc0de.abc123_x.tmp.ply",  # another host's: its process is unknown here
        ".scene.ply.tmp",  # not ours
        "scene.ply",
    ]
    for name in kept:
        (tmp_path / name).write_text("keep")
    removed = remove_leftovers(tmp_path)
    assert len(removed) == 2
    assert _tree(tmp_path) == sorted(kept)
    monkeypatch.setattr(atomic, "_cleaned", set())
    assert remove_leftovers(tmp_path) == []


def test_temporaries_of_a_killed_run_whose_process_id_is_taken_are_leftovers(tmp_path):
    """In a container every run may have one process id: a staging folder killed before its
    journal was judged by the id alone, alive for good, and never removed. The names carry the
    writer's start time; an earlier release's names (without it) are judged as before."""
    host, own = atomic._HOST, os.getpid()
    started = atomic._start_time(own)
    killed = tmp_path / f".staging.{own}-{host}-{int(started) - 1}.k2j3h4g5.tmp"  # this id, another start
    killed.mkdir()
    (killed / "1.png").write_text("killed run")
    kept = [f".scene.{own}-{host}-{started}.abc123_x.tmp.ply",  # this process's own
            f".scene.{own}-{host}.abc123_x.tmp.ply"]  # an earlier release's name: its id lives
    for name in kept:
        (tmp_path / name).write_text("keep")
    assert atomic.temporary_prefix("scene") == f".scene.{own}-{host}-{started}."
    assert remove_leftovers(tmp_path) == [killed]
    assert _tree(tmp_path) == sorted(kept)


def test_outputs_follow_the_umask(tmp_path):
    with atomic_path(tmp_path / "a.bin") as temporary:
        temporary.write_bytes(b"x")
    assert (tmp_path / "a.bin").stat().st_mode & 0o777 == 0o666 & ~atomic.current_umask()


def test_a_commit_a_killed_run_left_half_done_is_finished_by_the_next(tmp_path):
    """The journal's moves: old scene out of the way (done), new scene in (done), new cameras in
    (not done), manifest in (not done). The next run completes them, then removes the staging
    folder with the old files."""
    host, dead = atomic._HOST, _dead_pid()
    staging = tmp_path / f".staging.{dead}-{host}.k2j3h4g5.tmp"
    (staging / ".replaced").mkdir(parents=True)
    (staging / ".replaced" / "0").write_text("old scene")
    (tmp_path / "scene.ply").write_text("new scene")
    (tmp_path / "cameras.json").write_text("old cameras")
    old_manifest = Manifest(tmp_path, {"cameras.json": describe_file(tmp_path / "cameras.json", "restore", "restore")})
    (tmp_path / ".lumos3d-manifest.json").write_text(old_manifest.document())  # the old cameras are lumos3d's
    (staging / "cameras.json").write_text("new cameras")
    (staging / ".manifest.4").write_text("new manifest")
    moves = [[tmp_path / "scene.ply", staging / ".replaced" / "0", "destination-exists"],
             [staging / "scene.ply", tmp_path / "scene.ply", "source-gone"],
             [tmp_path / "cameras.json", staging / ".replaced" / "2", "destination-exists"],
             [staging / "cameras.json", tmp_path / "cameras.json", "source-gone"],
             [staging / ".manifest.4", tmp_path / ".lumos3d-manifest.json", "source-gone"]]
    (staging / COMMIT_JOURNAL).write_text(json.dumps({"folder": str(tmp_path), "other_folders": [],
                                                      "moves": [[str(a), str(b), c] for a, b, c in moves]}))
    assert remove_leftovers(tmp_path) == [staging]
    assert _tree(tmp_path) == [".lumos3d-manifest.json", "cameras.json", "scene.ply"]
    assert [(tmp_path / name).read_text() for name in ("scene.ply", "cameras.json", ".lumos3d-manifest.json")] == [
        "new scene", "new cameras", "new manifest"]


def test_a_journal_that_does_not_belong_to_its_folder_is_never_carried_out(tmp_path):
    """A copy of an output folder carries a killed run's journal along (its paths name the
    original folder); a relative, unreadable or outside path is not trusted either. Nothing moves,
    nothing is deleted, the staging folder stays (with a warning)."""
    host, dead = atomic._HOST, _dead_pid()
    victim = tmp_path / "elsewhere" / "cameras.json"
    victim.parent.mkdir()
    victim.write_text("the user's")
    for index, document in enumerate([
        {"folder": str(tmp_path / "original"), "other_folders": [], "moves": [[str(victim), "x", "destination-exists"]]},
        {"folder": str(tmp_path / f"copy{2}"), "other_folders": [], "moves": [["cameras.json", ".replaced/0", "destination-exists"]]},
        {"folder": str(tmp_path / f"copy{3}"), "other_folders": [],
         "moves": [[str(tmp_path / "copy3" / ".." / "elsewhere" / "cameras.json"), str(tmp_path / "copy3" / "t"), "destination-exists"]]},
        "{not json",
    ]):
        folder = tmp_path / f"copy{index}"
        staging = folder / f".staging.{dead}-{host}.k2j3h4g{index}.tmp"
        staging.mkdir(parents=True)
        (staging / COMMIT_JOURNAL).write_text(document if isinstance(document, str) else json.dumps(document))
        assert remove_leftovers(folder) == [] and staging.is_dir()
    assert victim.read_text() == "the user's"
