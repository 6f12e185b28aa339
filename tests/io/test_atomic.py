"""io/atomic.py: outputs appear whole or not at all; re-runs replace the folders a run owns and
nothing else; a killed run's temporaries are removed by the next run, a live run's are not."""

import os
import subprocess
import sys
import tempfile

import pytest

from lumos3d_cli.errors import InputError
from lumos3d_cli.io import atomic
from lumos3d_cli.io.atomic import atomic_directory, atomic_path, remove_leftovers


def _tree(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_a_failed_block_leaves_nothing_and_removes_the_folders_it_created(tmp_path):
    with pytest.raises(RuntimeError):
        with atomic_directory(tmp_path / "a" / "b") as staging:
            (staging / "x.txt").write_text("half")
            raise RuntimeError("failed while writing")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(tmp_path / "c" / "d.bin") as temporary:
            temporary.write_bytes(b"half")
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_merge_keeps_other_files_and_replace_folders_replaces_sub_folders_whole(tmp_path):
    out = tmp_path / "out"
    with atomic_directory(out) as staging:
        (staging / "views").mkdir()
        for name in ("1.png", "2.png", "3.png"):
            (staging / "views" / name).write_text("first")
        (staging / "scene.ply").write_text("first")
    (out / "notes.txt").write_text("the user's")
    with atomic_directory(out) as staging:  # merge: views/ gains and replaces files, keeps the rest
        (staging / "views").mkdir()
        (staging / "views" / "1.png").write_text("merged")
    assert (out / "views" / "1.png").read_text() == "merged" and (out / "views" / "3.png").exists()
    with atomic_directory(out, replace_folders=True) as staging:
        (staging / "views").mkdir()
        (staging / "views" / "2.png").write_text("second")
        (staging / "scene.ply").write_text("second")
    assert _tree(out) == ["notes.txt", "scene.ply", "views", "views/2.png"]
    assert (out / "scene.ply").read_text() == "second" and (out / "notes.txt").read_text() == "the user's"


def test_a_name_taken_by_the_other_kind_is_refused_before_anything_moves(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "views").write_text("a file where the output folder goes")
    with pytest.raises(InputError, match=r"out/views: is a file but the output written there is a folder"):
        with atomic_directory(out, replace_folders=True) as staging:
            (staging / "scene.ply").write_text("new")
            (staging / "views").mkdir()
    assert _tree(out) == ["views"]


def test_an_output_folder_under_a_regular_file_is_an_input_error(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match=r"cannot be created because .*/file is a file"):
        with atomic_directory(tmp_path / "file" / "out"):
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


def test_outputs_follow_the_umask(tmp_path):
    with atomic_path(tmp_path / "a.bin") as temporary:
        temporary.write_bytes(b"x")
    assert (tmp_path / "a.bin").stat().st_mode & 0o777 == 0o666 & ~atomic._current_umask()


def test_interrupt_right_after_the_staging_folder_is_made_leaves_nothing(tmp_path, monkeypatch):
    """A signal between mkdtemp making the staging folder and the code naming it (the window in
    which a restore stopped by Ctrl-C once left its staging folder behind)."""
    made = tempfile.mkdtemp

    def interrupted_mkdtemp(*args, **kwargs):
        made(*args, **kwargs)
        raise KeyboardInterrupt

    out = tmp_path / "out"
    out.mkdir()
    (out / "kept.txt").write_text("earlier run")
    monkeypatch.setattr(atomic.tempfile, "mkdtemp", interrupted_mkdtemp)
    with pytest.raises(KeyboardInterrupt):
        with atomic_directory(out):
            pass
    assert sorted(p.name for p in out.iterdir()) == ["kept.txt"]
