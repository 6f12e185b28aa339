"""io/output_set.py (with io/manifest.py and io/output_lock.py): a command writes only over files
lumos3d wrote, never over or into its inputs; one run per folder at a time; the new outputs
appear in one commit that a signal does not cut short; a failure leaves everything as it was."""

import contextlib
import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import pytest

from lumos3d_cli.errors import InputError, Interrupted
from lumos3d_cli.io import atomic
from lumos3d_cli.io.file_digest import file_sha256
from lumos3d_cli.io.manifest import MANIFEST_NAME, Manifest
from lumos3d_cli.io.output_lock import LOCK_NAME, folder_lock
from lumos3d_cli.io import output_set as output_set_module
from lumos3d_cli.io.output_set import OutputSet

from output_files import snapshot
from processes import hidden_entries


def _tree(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def _restore_like(out, views, inputs=(), text="new", video=None):
    """Write scene.ply, summary.json and views/<name> through an OutputSet, like a restore."""
    outputs = OutputSet(out, "restore", "restore scene.ply", inputs).add_file("scene.ply").add_file("summary.json")
    outputs.add_folder("views")
    if video is not None:
        outputs.add_elsewhere(video, "video")
    with outputs.staged() as staging:
        (staging.root / "scene.ply").write_text(text)
        (staging.root / "summary.json").write_text(text)
        (staging.root / "views").mkdir()
        for name in views:
            (staging.root / "views" / name).write_text(text)
        if video is not None:
            staging.files[video].write_text(text)
    return outputs


def test_a_rerun_replaces_its_own_files_removes_its_stale_ones_and_keeps_everything_else(tmp_path):
    out = tmp_path / "out"
    _restore_like(out, ["1.png", "2.png", "3.png"], text="first")
    manifest = Manifest.read(out)
    assert sorted(manifest.files) == ["scene.ply", "summary.json", "views/1.png", "views/2.png", "views/3.png"]
    assert all(entry.command == "restore" for entry in manifest.files.values())
    (out / "notes.txt").write_text("the user's")
    other = OutputSet(out, "render", "render").add_file("00000.png")
    with other.staged() as staging:
        (staging.root / "00000.png").write_text("a render")
    _restore_like(out, ["2.png"], text="second")
    assert _tree(out) == [MANIFEST_NAME, "00000.png", "notes.txt", "scene.ply", "summary.json", "views", "views/2.png"]
    assert [(out / name).read_text() for name in ("scene.ply", "views/2.png", "notes.txt", "00000.png")] == [
        "second", "second", "the user's", "a render"]
    assert sorted(Manifest.read(out).files) == ["00000.png", "scene.ply", "summary.json", "views/2.png"]


def test_a_stale_file_of_an_earlier_run_that_this_run_reads_is_kept(tmp_path, caplog):
    """An input linking to an earlier run's output (degrade D2 -o D with D2/zzz.png -> D/photo.png):
    the re-run neither writes over it nor removes it as stale."""
    out, inputs = tmp_path / "out", tmp_path / "inputs"
    with OutputSet(out, "degrade", "degrade").add_file("photo.png").add_file("other.png").staged() as staging:
        for name in ("photo.png", "other.png"):
            (staging.root / name).write_text("first")
    inputs.mkdir()
    (inputs / "zzz.png").symlink_to(out / "photo.png")
    with OutputSet(out, "degrade", "degrade", [inputs, inputs / "zzz.png"]).add_file("zzz.png").staged() as staging:
        (staging.root / "zzz.png").write_text((inputs / "zzz.png").read_text() + ", degraded")
    assert _tree(out) == [MANIFEST_NAME, "photo.png", "zzz.png"]  # other.png: stale, removed
    assert (inputs / "zzz.png").read_text() == "first" and (out / "zzz.png").read_text() == "first, degraded"
    assert "photo.png: kept: an earlier run's output, and an input of this run" in caplog.text
    assert sorted(Manifest.read(out).files) == ["photo.png", "zzz.png"]  # still the set's: a later run may remove it


@pytest.mark.parametrize("place", ["scene.ply", "views/notes.txt", "views/1.png"])
def test_a_file_lumos3d_did_not_write_is_refused_before_any_work_and_survives(tmp_path, place):
    out = tmp_path / "out"
    (out / "views").mkdir(parents=True)
    (out / place).write_text("the user's")
    outputs = OutputSet(out, "restore", "restore scene.ply").add_file("scene.ply").add_file("summary.json").add_folder("views")
    with pytest.raises(InputError, match=rf"out/{place}: exists and was not written by lumos3d"):
        outputs.check()
    with pytest.raises(InputError, match=rf"out/{place}: exists and was not written by lumos3d"):
        _restore_like(out, ["1.png"])
    assert (out / place).read_text() == "the user's"
    assert _tree(out) == sorted(["views", place])


def test_a_file_of_ours_the_user_changed_is_theirs_now(tmp_path):
    out = tmp_path / "out"
    _restore_like(out, ["1.png"], text="first")
    (out / "views" / "1.png").write_text("edited by hand")
    with pytest.raises(InputError, match=r"views/1.png: was changed since lumos3d wrote it"):
        _restore_like(out, ["1.png"])
    assert (out / "views" / "1.png").read_text() == "edited by hand" and (out / "scene.ply").read_text() == "first"


def test_a_folder_the_user_made_inside_a_folder_of_ours_is_refused(tmp_path):
    out = tmp_path / "out"
    _restore_like(out, ["1.png"])
    (out / "views" / "mine").mkdir()
    with pytest.raises(InputError, match=r"views/mine: a folder lumos3d did not make"):
        _restore_like(out, ["1.png"])


def test_a_name_taken_by_the_other_kind_is_refused_before_anything_moves(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "views").write_text("a file where the output folder goes")
    (out / "summary.json").mkdir()
    with pytest.raises(InputError, match=r"out/summary.json: is a folder where lumos3d writes a file"):
        _restore_like(out, ["1.png"])
    (out / "summary.json").rmdir()
    with pytest.raises(InputError, match=r"out/views: is a file where lumos3d writes its folder views/"):
        _restore_like(out, ["1.png"])
    assert _tree(out) == ["views"]


def test_a_failed_block_leaves_nothing_and_removes_the_folders_it_created(tmp_path):
    outputs = OutputSet(tmp_path / "a" / "b", "degrade").add_file("x.png")
    with pytest.raises(RuntimeError):
        with outputs.staged() as staging:
            (staging.root / "x.png").write_text("half")
            raise RuntimeError("failed while writing")
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_is_an_input_error_naming_the_file_and_changes_nothing(tmp_path):
    out = tmp_path / "out"
    _restore_like(out, ["1.png"], text="first")
    before = {name: (out / name).read_bytes() for name in _tree(out) if (out / name).is_file()}
    outputs = OutputSet(out, "restore", "restore scene.ply").add_file("scene.ply")
    with pytest.raises(InputError, match=r"scene.ply: no space left on the device while writing the outputs"):
        with outputs.staged() as staging:
            raise OSError(errno.ENOSPC, "No space left on device", str(staging.root / "scene.ply"))
    assert {name: (out / name).read_bytes() for name in _tree(out) if (out / name).is_file()} == before


def test_an_interrupt_right_after_the_staging_folder_is_made_leaves_nothing(tmp_path, monkeypatch):
    """A signal between mkdtemp making the staging folder and the code naming it."""
    made = tempfile.mkdtemp

    def interrupted_mkdtemp(*args, **kwargs):
        made(*args, **kwargs)
        raise KeyboardInterrupt

    out = tmp_path / "out"
    out.mkdir()
    (out / "kept.txt").write_text("the user's")
    monkeypatch.setattr(tempfile, "mkdtemp", interrupted_mkdtemp)
    with pytest.raises(KeyboardInterrupt):
        with OutputSet(out, "degrade").add_file("x.png").staged():
            pass
    assert _tree(out) == ["kept.txt"]


def test_a_signal_during_the_commit_takes_effect_once_the_new_set_is_complete(tmp_path, monkeypatch):
    out = tmp_path / "out"
    _restore_like(out, ["1.png", "2.png"], text="first")
    original, calls = os.replace, []

    def replace_then_signal(source, destination):
        calls.append(destination)
        if len(calls) == 2:  # between two renames of the commit: the old scene is gone, the new one not yet in
            os.kill(os.getpid(), signal.SIGINT)
        original(source, destination)

    monkeypatch.setattr(os, "replace", replace_then_signal)
    with pytest.raises(KeyboardInterrupt):
        _restore_like(out, ["1.png"], text="second")
    monkeypatch.setattr(os, "replace", original)
    assert len(calls) > 2
    assert _tree(out) == [MANIFEST_NAME, "scene.ply", "summary.json", "views", "views/1.png"]
    assert {(out / name).read_text() for name in ("scene.ply", "summary.json", "views/1.png")} == {"second"}


def test_a_file_elsewhere_commits_with_the_set_and_is_owned_through_its_folders_manifest(tmp_path):
    out, videos = tmp_path / "out", tmp_path / "videos"
    _restore_like(out, ["1.png"], video=videos / "orbit.mp4", text="first")
    assert (videos / "orbit.mp4").read_text() == "first" and sorted(Manifest.read(videos).files) == ["orbit.mp4"]
    _restore_like(out, ["1.png"], video=videos / "orbit.mp4", text="second")
    assert (videos / "orbit.mp4").read_text() == "second"
    assert _tree(videos) == [MANIFEST_NAME, "orbit.mp4"]
    (videos / "mine.mp4").write_text("the user's")
    with pytest.raises(InputError, match=r"videos/mine.mp4: exists and was not written by lumos3d"):
        _restore_like(out, ["1.png"], video=videos / "mine.mp4")


def test_outputs_stay_clear_of_the_inputs(tmp_path):
    photos = tmp_path / "d" / "images"
    photos.mkdir(parents=True)
    (photos / "1.jpg").write_text("photo")
    poses = tmp_path / "d" / "views" / "sparse"
    poses.mkdir(parents=True)
    cases = [
        (tmp_path / "d", [photos / "1.jpg", poses], r"views: would hold the outputs, but it holds the input"),
        (photos, [photos], r"images: is the input folder"),
        (photos / "out", [photos], r"lies inside the input folder"),
        (tmp_path / "d", [tmp_path / "d" / "scene.ply"], r"scene.ply: is an input"),
    ]
    for out, inputs, message in cases:
        with pytest.raises(InputError, match=message):
            OutputSet(out, "restore", inputs=inputs).add_file("scene.ply").add_folder("views").check()
    # the nerfstudio layout: photos in d/images, outputs in d/
    OutputSet(tmp_path / "d", "restore", inputs=[photos, photos / "1.jpg"]).add_file("scene.ply").add_folder("restored").check()
    link = tmp_path / "link.ply"
    link.symlink_to(photos / "1.jpg")
    with pytest.raises(InputError, match=r"link.ply: is an input"):
        OutputSet(tmp_path, "convert", inputs=[photos / "1.jpg"]).add_file("link.ply").check()


def test_a_second_run_into_the_same_folder_is_refused_naming_the_first(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import sys, time
        from lumos3d_cli.io.output_lock import folder_lock
        with folder_lock({str(out)!r}, "restore"):
            print("locked", flush=True)
            time.sleep(60)
    """)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(InputError, match=rf"out: `lumos3d restore`, process {holder.pid} .* is writing its outputs here"):
            with OutputSet(out, "render").add_file("00000.png").staged():
                pass
        # the check a command makes before loading its libraries refuses too, and leaves the lock as it was
        with pytest.raises(InputError, match=rf"out: `lumos3d restore`, process {holder.pid} .* is writing its outputs here"):
            OutputSet(out, "render").add_file("00000.png").check()
        assert json.loads((out / LOCK_NAME).read_text())["pid"] == holder.pid
    finally:
        holder.kill()
        holder.wait()
    # its lock ends with the process, however it ends
    _restore_like(out, ["1.png"])
    assert not (out / LOCK_NAME).exists()


def test_a_run_writing_inside_an_output_folder_is_named_and_its_leftovers_go_with_the_folder(tmp_path):
    """`render -o out/restored` running (or killed) while a restore replaces out/restored: its lock
    and staging folder there were taken for the user's files ("exists and was not written by
    lumos3d; move it away"): a live run's lock told the user to move it, and a killed run's
    leftovers refused every restore into the folder."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png"])
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import time
        from lumos3d_cli.io.output_set import OutputSet
        with OutputSet({str(out / "views")!r}, "render").add_file("00000.png").staged() as staging:
            (staging.root / "00000.png").write_text("frame")
            print("staged", flush=True)
            time.sleep(60)
    """)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "staged"
        with pytest.raises(InputError, match=rf"views: `lumos3d render`, process {holder.pid} .* is writing its outputs here"):
            _restore_like(out, ["1.png"], text="second")
    finally:
        holder.kill()  # a killed run cleans nothing up
        holder.wait()
    assert LOCK_NAME in os.listdir(out / "views") and any(name.startswith(".") and name.endswith(".tmp")
                                                          for name in os.listdir(out / "views"))
    _restore_like(out, ["1.png"], text="second")
    assert sorted(os.listdir(out / "views")) == ["1.png"] and (out / "views" / "1.png").read_text() == "second"


def test_the_lock_is_reentrant_within_a_process(tmp_path):
    with folder_lock(tmp_path, "restore"):
        with folder_lock(tmp_path, "restore"):
            assert json.loads((tmp_path / LOCK_NAME).read_text())["pid"] == os.getpid()
        assert (tmp_path / LOCK_NAME).exists()
    assert not (tmp_path / LOCK_NAME).exists()


def test_leftover_staging_of_a_killed_commit_is_rolled_forward_when_the_next_run_starts(tmp_path, monkeypatch):
    """The commit's journal as a killed run leaves it: made by a real commit whose process 'died'
    after its second move (os.replace raising SystemExit stands for the kill)."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png"], text="first")
    original, calls = os.replace, []

    def killed_after_two(source, destination):
        if (".staging." in str(source)) != (".staging." in str(destination)):  # a move of the commit
            if len(calls) == 2:
                raise SystemExit("killed")
            calls.append(destination)
        original(source, destination)

    monkeypatch.setattr(os, "replace", killed_after_two)
    monkeypatch.setattr(sys.modules["shutil"], "rmtree", lambda *args, **kwargs: None)  # a killed run cleans nothing
    with pytest.raises(SystemExit):
        _restore_like(out, ["1.png"], text="second")
    monkeypatch.undo()
    staging = next(p for p in out.iterdir() if p.name.startswith(".staging."))
    assert (staging / atomic.COMMIT_JOURNAL).is_file() and (out / "scene.ply").read_text() == "second"
    monkeypatch.setattr(atomic, "_process_exists", lambda pid: False)  # its process has ended
    monkeypatch.setattr(atomic, "_cleaned", set())
    atomic.remove_leftovers(out)
    assert _tree(out) == [MANIFEST_NAME, "scene.ply", "summary.json", "views", "views/1.png"]
    assert {(out / name).read_text() for name in ("scene.ply", "summary.json", "views/1.png")} == {"second"}
    _restore_like(out, ["1.png"], text="third")  # and the manifest owns the result


def _kill_mid_commit(out, monkeypatch, after=2, video=None, text="killed") -> bool:
    """A restore-like commit of `text` into `out` (with `video`) whose process 'dies' after `after`
    of the moves that follow its journal (os.replace raising SystemExit stands for SIGKILL; a
    killed run cleans nothing up); False when the commit has fewer moves and completed."""
    original_replace, original_journal, calls, armed = os.replace, output_set_module.write_commit_journal, [], []

    def journal(*args, **kwargs):
        original_journal(*args, **kwargs)
        armed.append(True)

    def killed(source, destination):
        if armed:
            if len(calls) == after:
                raise SystemExit("killed")
            calls.append(destination)
        original_replace(source, destination)

    with monkeypatch.context() as patch:
        patch.setattr(output_set_module, "write_commit_journal", journal)
        patch.setattr(os, "replace", killed)
        patch.setattr(sys.modules["shutil"], "rmtree", lambda *args, **kwargs: None)
        patch.setattr(output_set_module, "remove_path", lambda *args, **kwargs: None)
        patch.setattr(Path, "unlink", lambda *args, **kwargs: None)
        try:
            _restore_like(out, ["1.png"], text=text, video=video)
        except SystemExit:
            return True
    return False


def test_the_next_run_of_the_same_command_finishes_a_killed_commit_then_runs(tmp_path, monkeypatch):
    out = tmp_path / "out"
    _restore_like(out, ["1.png", "2.png"], text="first")
    assert _kill_mid_commit(out, monkeypatch)
    monkeypatch.setattr(atomic, "_process_exists", lambda pid: False)
    monkeypatch.setattr(atomic, "_cleaned", set())
    # the check a command makes before loading its libraries leaves the half-moved set to the
    # recovery under the lock (it called the killed run's new files "changed since lumos3d wrote them")
    OutputSet(out, "restore", "restore scene.ply").add_file("scene.ply").add_file("summary.json").add_folder("views").check()
    _restore_like(out, ["1.png"], text="third")  # no "was changed since lumos3d wrote it"
    assert _tree(out) == [MANIFEST_NAME, "scene.ply", "summary.json", "views", "views/1.png"]


def test_finishing_a_killed_commit_keeps_what_the_user_made_or_edited_since(tmp_path, monkeypatch, caplog):
    """The recovery replayed the journal blind: a file the user put where the killed run had
    moved its old output away was overwritten, and an old output the user edited since was moved
    away and deleted with the staging folder."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png", "2.png"], text="first")
    assert _kill_mid_commit(out, monkeypatch, after=1)  # scene.ply moved away, the new one not yet in
    assert not (out / "scene.ply").exists()
    (out / "scene.ply").write_text("the user's")
    with open(out / "summary.json", "a") as handle:
        handle.write(" edited")
    monkeypatch.setattr(atomic, "_process_exists", lambda pid: False)
    monkeypatch.setattr(atomic, "_cleaned", set())
    atomic.remove_leftovers(out)
    assert (out / "scene.ply").read_text() == "the user's"
    assert (out / "summary.json").read_text() == "first edited"
    assert (out / "views" / "1.png").read_text() == "killed" and not (out / "views" / "2.png").exists()
    assert "kept: made after a run was killed" in caplog.text and "kept: changed since lumos3d wrote it" in caplog.text
    # the manifest says so: the user's two files are not lumos3d's (it listed the killed run's digests for them)
    manifest = Manifest.read(out)
    assert sorted(manifest.files) == ["views/1.png"] and manifest.owns(out / "views" / "1.png")
    assert caplog.text.count("summary.json: kept") == 1  # one message for the edited file, not a second, false one
    with pytest.raises(InputError, match="scene.ply: exists and was not written by lumos3d"):  # theirs: a next run refuses
        _restore_like(out, ["1.png"], text="third")


def test_an_old_folder_of_outputs_the_user_added_to_is_kept_whole_and_stays_lumos3ds(tmp_path, monkeypatch):
    """After a kill, the user put a file into the old views/: the recovery kept the old folder
    (right) but moved in the killed run's manifest, which listed the new views' digests, so the
    untouched old views counted as the user's and the manifest named files that were not there."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png", "2.png"], text="first")
    assert _kill_mid_commit(out, monkeypatch, after=1)  # before views/ moves
    (out / "views" / "mine.txt").write_text("the user's")
    monkeypatch.setattr(atomic, "_process_exists", lambda pid: False)
    monkeypatch.setattr(atomic, "_cleaned", set())
    atomic.remove_leftovers(out)
    manifest = Manifest.read(out)
    assert sorted(p.name for p in (out / "views").iterdir()) == ["1.png", "2.png", "mine.txt"]
    assert {name for name in manifest.files if name.startswith("views/")} == {"views/1.png", "views/2.png"}
    assert manifest.owns(out / "views" / "1.png") and manifest.owns(out / "views" / "2.png")
    assert all((out / name).is_file() for name in manifest.files)


def test_a_killed_commit_whose_process_id_was_reused_is_still_finished(tmp_path, monkeypatch):
    """Only the process id told a killed run from a live one: with the id taken by another process
    (after a reboot, in a container) the half-done commit was never finished, a later run was
    refused (calling the killed run's new files the user's), and once the id was free the journal
    was replayed over the newer outputs. The journal names its writer's start time and boot."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png", "2.png"], text="first")
    assert _kill_mid_commit(out, monkeypatch)  # its writer: this process, which still lives
    monkeypatch.setattr(atomic, "_cleaned", set())
    assert not atomic.holds_unfinished_commit(out)  # the writer itself is still at work, as far as can be told
    started = atomic._start_time(os.getpid())
    monkeypatch.setattr(atomic, "_start_time", lambda pid: str(int(started) + 1))  # the id's process started later
    assert atomic.holds_unfinished_commit(out)
    _restore_like(out, ["1.png"], text="third")
    assert _tree(out) == [MANIFEST_NAME, "scene.ply", "summary.json", "views", "views/1.png"]
    assert (out / "scene.ply").read_text() == "third"


def test_a_killed_commit_with_a_video_whose_process_id_was_reused_is_finished_before_a_run_into_its_folder(
        tmp_path, monkeypatch):
    """With the killed run's process id alive (here: this process, as in a container where every
    run is process 1), its marker in the video's folder was judged by the id alone: a run into that
    folder did not finish the commit first, its video was later moved aside by the recovery and
    replaced by the killed run's, its manifest overwritten, and the killed run's temporaries there
    stayed for good."""
    out, videos = tmp_path / "out", tmp_path / "videos"
    _restore_like(out, ["1.png"], video=videos / "orbit.mp4", text="first")
    assert _kill_mid_commit(out, monkeypatch, after=7, video=videos / "orbit.mp4")  # old video aside, new not in
    started = atomic._start_time(os.getpid())
    monkeypatch.setattr(atomic, "_start_time", lambda pid: str(int(started) + 1))  # the id's process started later
    monkeypatch.setattr(atomic, "_cleaned", set())
    assert atomic.folders_of_pending_commits(videos) == [out.resolve()]
    _restore_like(tmp_path / "out2", ["1.png"], video=videos / "orbit.mp4", text="B")  # a later run into the video's folder
    assert (videos / "orbit.mp4").read_text() == "B" and Manifest.read(videos).owns(videos / "orbit.mp4")
    assert hidden_entries(videos) == [] and not atomic.holds_unfinished_commit(out)
    assert (out / "scene.ply").read_text() == "killed"  # the killed run's commit, finished first
    _restore_like(out, ["1.png"], text="third")
    assert (videos / "orbit.mp4").read_text() == "B"


def test_a_stale_file_inside_a_folder_of_outputs_is_judged_by_the_output_folders_manifest(tmp_path):
    """out/views/1.png is listed in out's manifest ("views/1.png"), not in a manifest of views/: the
    recovery's check took lumos3d's own unchanged file for the user's."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png"])
    assert atomic._still_written_by_lumos3d((out / "views" / "1.png").resolve(), out.resolve())
    assert atomic._still_written_by_lumos3d((out / "views").resolve(), out.resolve())
    (out / "views" / "1.png").write_text("edited")
    assert not atomic._still_written_by_lumos3d((out / "views" / "1.png").resolve(), out.resolve())


def test_a_copied_folder_never_replays_the_journal_it_carries(tmp_path, monkeypatch):
    out = tmp_path / "out"
    _restore_like(out, ["1.png"], text="first")
    assert _kill_mid_commit(out, monkeypatch)
    copy = shutil.copytree(out, tmp_path / "copy", symlinks=True)
    before = snapshot(out)
    monkeypatch.setattr(atomic, "_process_exists", lambda pid: False)
    monkeypatch.setattr(atomic, "_cleaned", set())
    atomic.remove_leftovers(copy)
    assert snapshot(out) == before and any(p.name.startswith(".staging.") for p in copy.iterdir())


@pytest.mark.parametrize("where", ["elsewhere", "beside", "below", "dotdot", "link"])
def test_a_commit_with_a_video_killed_at_any_move_loses_nothing(tmp_path, monkeypatch, where):
    """A restore with --video, killed (SIGKILL) after any number of its moves; then a run into the
    video's folder, then one into the output folder. The video was lost: a run into its folder took
    the killed commit's temporaries there for leftovers (`videos/`, `out/sub/`), a run into the
    output folder deleted the video staged beside the staging folder when it came first in the
    listing (`out/`), and a path through `..` made the journal untrusted for good. Now every
    folder ends with the complete newest set, whatever the moment of the kill."""
    after = 0
    while True:
        root = tmp_path / str(after)
        out = root / "out"
        videos = {"elsewhere": root / "videos", "beside": out, "below": out / "sub", "dotdot": root / "videos",
                  "link": root / "link"}[where]
        video = videos / "orbit.mp4"
        if where == "dotdot":
            video = root / "videos" / ".." / "videos" / "orbit.mp4"
        (root / "videos").mkdir(parents=True)
        out.mkdir()
        if where == "link":
            videos.symlink_to(out, target_is_directory=True)
        _restore_like(out, ["1.png"], text="first", video=video)
        if not _kill_mid_commit(out, monkeypatch, after, video=video, text="second"):
            break
        with monkeypatch.context() as patch:
            patch.setattr(atomic, "_process_exists", lambda pid: pid == os.getpid())  # the killed run has ended
            patch.setattr(os, "getpid", lambda: 1)  # the next runs are other processes
            patch.setattr(atomic, "_cleaned", set())
            listing = atomic._entries  # the worst order: the staged video listed before the staging folder
            patch.setattr(atomic, "_entries", lambda folder: sorted(listing(folder), key=lambda p: ".staging." in p.name))
            poster = OutputSet(videos, "degrade", "degrade poster.png").add_file("poster.png")
            poster.check()  # not refused over the half-moved set
            with poster.staged() as staging:
                (staging.root / "poster.png").write_text("poster")
            _restore_like(out, ["1.png"], text="third", video=video)
        assert (videos / "orbit.mp4").read_text() == "third" and (videos / "poster.png").read_text() == "poster", after
        assert hidden_entries(root) == [], after
        assert {(out / name).read_text() for name in ("scene.ply", "summary.json", "views/1.png")} == {"third"}, after
        after += 1
    assert after >= 8  # every move of the commit was a moment of the kill


def test_a_recovery_cut_short_never_replays_a_finished_commit(tmp_path, monkeypatch):
    """The recovery removed the staging folder with the journal still in it: cut short after its
    `.replaced` went, the next recovery 'finished' the moves again and deleted the new set."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png"], text="first")
    assert _kill_mid_commit(out, monkeypatch)
    monkeypatch.setattr(atomic, "_process_exists", lambda pid: False)
    monkeypatch.setattr(atomic, "_cleaned", set())
    removed_first = []

    def cut_short(path):
        shutil.rmtree(path / ".replaced")  # what an rmtree reached first
        removed_first.append(path)
        raise SystemExit("killed")

    with monkeypatch.context() as patch:
        patch.setattr(atomic, "remove_path", cut_short)
        with pytest.raises(SystemExit):
            atomic.remove_leftovers(out)
    assert removed_first and (out / "scene.ply").read_text() == "killed"
    monkeypatch.setattr(atomic, "_cleaned", set())
    atomic.remove_leftovers(out)
    assert {(out / name).read_text() for name in ("scene.ply", "summary.json", "views/1.png")} == {"killed"}
    assert hidden_entries(out) == []


def test_a_move_that_fails_during_the_commit_puts_the_old_set_back(tmp_path, monkeypatch):
    out = tmp_path / "out"
    _restore_like(out, ["1.png", "2.png"], text="first")
    before = snapshot(out)
    original = os.replace

    def refused(source, destination):
        if str(source).endswith("/views") and ".staging." not in str(source):  # the old views/ cannot move
            raise PermissionError(errno.EPERM, "Operation not permitted", str(source))
        original(source, destination)

    monkeypatch.setattr(os, "replace", refused)
    with pytest.raises(InputError, match=r"out/views: cannot be replaced \(Operation not permitted\); nothing was changed"):
        _restore_like(out, ["1.png"], text="second")
    monkeypatch.setattr(os, "replace", original)
    assert snapshot(out) == before and hidden_entries(out) == []


def test_a_lock_file_that_is_not_lumos3ds_is_never_written_or_removed(tmp_path):
    precious = tmp_path / "precious.txt"
    precious.write_text("the user's")
    for out, make in ((tmp_path / "linked", lambda lock: lock.symlink_to(precious)),
                      (tmp_path / "own", lambda lock: lock.write_text("the user's own .lumos3d.lock")),
                      (tmp_path / "folder", lambda lock: lock.mkdir())):
        out.mkdir()
        make(out / LOCK_NAME)
        with pytest.raises(InputError, match=r"\.lumos3d\.lock: is not lumos3d's lock file"):
            _restore_like(out, ["1.png"])
        assert os.path.lexists(out / LOCK_NAME) and not (out / "scene.ply").exists()
    assert precious.read_text() == "the user's" and (tmp_path / "own" / LOCK_NAME).read_text() == "the user's own .lumos3d.lock"


def test_a_lock_file_that_goes_or_comes_empty_never_wedges_the_folder(tmp_path, monkeypatch):
    """Another run ended (removing its lock file) between this run's look for the file and its
    open with O_CREAT: this run made an empty file, took it for the user's, refused, and left it,
    which refused every later run. Also an empty file a run killed before writing its record
    leaves: taken over, as a killed run's record is."""
    out = tmp_path / "out"
    out.mkdir()
    (out / LOCK_NAME).write_text("")  # killed between making the file and writing its record
    _restore_like(out, ["1.png"])
    assert not (out / LOCK_NAME).exists() and (out / "scene.ply").is_file()
    original, opened = os.open, []

    def the_other_run_ends_meanwhile(path, flags, *args):
        if Path(path).name == LOCK_NAME and flags & os.O_EXCL and not opened:
            opened.append(path)
            raise FileExistsError(errno.EEXIST, "File exists", str(path))  # its file was there, and is gone now
        return original(path, flags, *args)

    monkeypatch.setattr(os, "open", the_other_run_ends_meanwhile)
    _restore_like(out, ["1.png"], text="second")
    assert opened and not (out / LOCK_NAME).exists()
    monkeypatch.setattr(os, "open", original)
    _restore_like(out, ["1.png"], text="third")


def test_an_earlier_output_that_cannot_be_read_is_named_not_an_internal_error(tmp_path, monkeypatch):
    """summary.json of an earlier run made unreadable to this user (chmod 600, another owner): a
    PermissionError out of the digest was an internal error."""
    import lumos3d_cli.io.manifest as manifest_module

    out = tmp_path / "out"
    _restore_like(out, ["1.png"])
    original = manifest_module.file_sha256

    def unreadable(path):
        if Path(path).name == "summary.json":
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return original(path)

    monkeypatch.setattr(manifest_module, "file_sha256", unreadable)
    with pytest.raises(InputError, match=r"out/summary.json: cannot be read \(Permission denied\) to tell whether it is "
                                         r"still what lumos3d wrote; make it readable"):
        _restore_like(out, ["1.png"], text="second")
    assert (out / "summary.json").read_text() == "new"


def test_a_file_of_the_users_under_the_manifests_name_is_refused_not_replaced(tmp_path):
    """A user's notes named .lumos3d-manifest.json drew two "cannot be read" warnings and were
    replaced by a manifest."""
    out = tmp_path / "out"
    out.mkdir()
    (out / MANIFEST_NAME).write_text("my private notes")
    with pytest.raises(InputError, match=r"\.lumos3d-manifest\.json: is not lumos3d's manifest file but takes its name"):
        _restore_like(out, ["1.png"])
    assert (out / MANIFEST_NAME).read_text() == "my private notes" and not (out / "scene.ply").exists()


def test_a_lock_file_that_cannot_be_removed_at_the_end_leaves_the_runs_own_error(tmp_path, monkeypatch, caplog):
    """The output folder made read-only during a run: removing the lock raised PermissionError
    from the lock's exit, an internal error that hid the run's own message."""
    out = tmp_path / "out"
    out.mkdir()
    original = os.unlink

    def read_only(path, *args, **kwargs):
        if Path(path).name == LOCK_NAME:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return original(path, *args, **kwargs)

    monkeypatch.setattr(os, "unlink", read_only)
    with pytest.raises(InputError, match="the run's own"):
        with folder_lock(out, "restore"):
            raise InputError("the run's own refusal")
    assert f"{LOCK_NAME}: cannot be removed (Permission denied)" in caplog.text


def test_readers_of_a_folder_a_killed_commit_left_half_done_are_warned(tmp_path, monkeypatch, caplog):
    """render, view, restore --poses and degrade read a folder holding a killed run's half-moved
    outputs (the new cameras beside the old scene) without a word."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png", "2.png"], text="first")
    atomic.warn_if_mid_commit(out / "scene.ply")
    assert "was killed while it moved its outputs" not in caplog.text  # a whole folder: no warning
    assert _kill_mid_commit(out, monkeypatch)
    monkeypatch.setattr(atomic, "_process_exists", lambda pid: False)
    monkeypatch.setattr(atomic, "_warned_mid_commit", set())
    (out / "frames").mkdir()  # another run's complete outputs inside it (render -o out/frames)
    atomic.warn_if_mid_commit(out / "frames" / "00000.png")
    assert "was killed while it moved its outputs" not in caplog.text
    atomic.warn_if_mid_commit(out / "views" / "1.png")  # a folder of outputs of its own: the same set
    assert f"{out}: a run writing here was killed while it moved its outputs into place" in caplog.text


def test_info_on_a_folder_a_killed_commit_left_half_done_warns(tmp_path, monkeypatch, caplog):
    """`lumos3d info OUT/` summarised the killed run's new files beside the earlier run's as one set."""
    from lumos3d_cli.cli.info import collect_summaries

    out = tmp_path / "out"
    _restore_like(out, ["1.png", "2.png"], text="first")
    assert _kill_mid_commit(out, monkeypatch)
    monkeypatch.setattr(atomic, "_process_exists", lambda pid: False)
    monkeypatch.setattr(atomic, "_warned_mid_commit", set())
    with pytest.raises(InputError):  # the stand-in outputs are text, not scenes
        collect_summaries(out)
    assert f"{out}: a run writing here was killed while it moved its outputs into place" in caplog.text


def test_a_manifest_naming_a_file_outside_its_folder_never_removes_it(tmp_path):
    out = tmp_path / "out"
    _restore_like(out, ["1.png"], text="first")
    victim = tmp_path / "victim.txt"
    victim.write_text("the user's")
    document = json.loads((out / MANIFEST_NAME).read_text())
    entry = dict(document["files"]["scene.ply"], bytes=victim.stat().st_size, sha256=file_sha256(victim))
    document["files"]["../victim.txt"] = entry
    (out / MANIFEST_NAME).write_text(json.dumps(document))
    _restore_like(out, ["1.png"], text="second")
    assert victim.read_text() == "the user's"


def test_a_file_elsewhere_gets_the_umask_and_never_goes_inside_a_folder_of_lumos3ds_own(tmp_path):
    out = tmp_path / "out"
    _restore_like(out, ["1.png"], video=out / "orbit.mp4")
    assert (out / "orbit.mp4").stat().st_mode & 0o777 == 0o666 & ~atomic.current_umask()
    with pytest.raises(InputError, match=r"orbit.mp4: lies inside .*out/views, which holds only the outputs"):
        _restore_like(out, ["1.png"], video=out / "views" / "orbit.mp4")


def test_another_runs_outputs_inside_a_folder_of_lumos3ds_own_refuse_the_run_and_survive(tmp_path):
    """`render -o out/views` puts frames and their manifest inside restore's own folder: they are
    lumos3d's, but another run's, so the next restore, which replaces the folder whole, refuses
    instead of deleting them; once they are moved away it runs."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png"])
    frames = OutputSet(out / "views", "render", "render").add_file("00000.png")
    with frames.staged() as staging:
        (staging.root / "00000.png").write_text("a frame")
    before = snapshot(out)
    with pytest.raises(InputError, match=r"views/00000.png: an output of another lumos3d run \(render\)"):
        _restore_like(out, ["2.png"], text="second")
    assert snapshot(out) == before
    (out / "views" / "00000.png").unlink()
    _restore_like(out, ["2.png"], text="second")
    assert _tree(out / "views") == ["2.png"]


def test_a_run_into_another_runs_folder_of_outputs_names_that_run(tmp_path):
    """`degrade P -o out/restored` where restore wrote out/restored/1.png said the file "was not
    written by lumos3d": it was, and out's manifest lists it."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png"])
    before = snapshot(out)
    with pytest.raises(InputError, match=r"views/1.png: an output of an earlier `restore`, part of its outputs in "):
        frames = OutputSet(out / "views", "degrade", "degrade").add_file("1.png")
        with frames.staged() as staging:
            (staging.root / "1.png").write_text("dark")
    assert snapshot(out) == before


def test_a_scene_of_another_name_never_takes_over_an_earlier_scenes_side_files(tmp_path):
    """Two restores into one folder under different scene names would share summary.json and
    views/: the second is refused while the first scene's file is there, so no scene is left with
    another's side files; with it moved away the second replaces them."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png"], text="first")
    second = OutputSet(out, "restore", "restore other.ply").add_file("other.ply").add_file("summary.json")
    second.add_folder("views")
    before = snapshot(out)
    with pytest.raises(InputError, match=r"holds the outputs of restore scene.ply \(scene.ply and"):
        second.check()
    assert snapshot(out) == before
    (out / "scene.ply").rename(tmp_path / "kept.ply")
    second.check()
    with second.staged() as staging:
        for name in ("other.ply", "summary.json"):
            (staging.root / name).write_text("second")
        (staging.root / "views").mkdir()
    assert _tree(out) == [MANIFEST_NAME, "other.ply", "summary.json", "views"]


def _journal_seen_at_staging_removal(monkeypatch) -> list[bool]:
    """Whether each staging folder still held its commit journal when its removal began (filled
    as shutil.rmtree is called)."""
    seen, original = [], shutil.rmtree

    def record(path, *args, **kwargs):
        if ".staging." in str(path):
            seen.append((Path(path) / atomic.COMMIT_JOURNAL).exists())
        return original(path, *args, **kwargs)

    monkeypatch.setattr(shutil, "rmtree", record)
    return seen


def test_the_journal_is_gone_before_the_staging_folder_is_removed(tmp_path, monkeypatch):
    """A kill while the staging folder is removed must leave no journal: the next run would
    "finish" the moves whose .replaced entries were already removed, and take the new outputs away."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png"], text="first")
    seen = _journal_seen_at_staging_removal(monkeypatch)
    _restore_like(out, ["1.png"], text="second")
    assert seen and not any(seen) and (out / "views" / "1.png").read_text() == "second"


def test_a_file_elsewhere_has_its_folders_manifest_staged_in_that_folder(tmp_path, monkeypatch):
    """A video on another file system: its folder's manifest was staged in the output folder's
    staging area, and the rename across file systems failed after all the work."""
    out, videos = tmp_path / "out", tmp_path / "videos"
    original, moved = os.replace, []

    def across_devices(source, destination):
        source, destination = Path(source), Path(destination)
        if (videos in destination.parents) != (videos in source.parents):
            raise OSError(errno.EXDEV, "Invalid cross-device link", str(source))
        moved.append(destination)
        original(source, destination)

    monkeypatch.setattr(os, "replace", across_devices)
    _restore_like(out, ["1.png"], video=videos / "orbit.mp4", text="first")
    assert videos / MANIFEST_NAME in moved and (videos / "orbit.mp4").read_text() == "first"
    assert _tree(videos) == [MANIFEST_NAME, "orbit.mp4"]


def test_a_signal_before_the_first_move_says_nothing_changed(tmp_path, monkeypatch):
    """A signal held over from the journal's writing lands before any move: the old set stays,
    and the message must not claim the new one is in place."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png"], text="first")
    before = snapshot(out)
    @contextlib.contextmanager
    def a_signal_delivered_on_entry():  # Python runs a handler once the journal's fsync returns: here
        raise Interrupted(signal.SIGTERM)
        yield

    monkeypatch.setattr(output_set_module, "_stop_signals_held", a_signal_delivered_on_entry)
    with pytest.raises(Interrupted) as stopped:
        _restore_like(out, ["1.png"], text="second")
    assert stopped.value.detail == "" and "nothing half-written" in stopped.value.message()
    assert snapshot(out) == before and hidden_entries(out) == []



def test_a_failed_commit_removes_its_journal_before_its_staging_folder(tmp_path, monkeypatch):
    """After a move fails and is undone, a kill while the staging folder is removed must not leave
    a journal whose "finish" would move the restored old outputs away."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png"], text="first")
    original = os.replace

    def refused(source, destination):
        if str(source).endswith("/views") and ".staging." not in str(source):
            raise PermissionError(errno.EPERM, "Operation not permitted", str(source))
        original(source, destination)

    monkeypatch.setattr(os, "replace", refused)
    seen = _journal_seen_at_staging_removal(monkeypatch)
    with pytest.raises(InputError, match="cannot be replaced"):
        _restore_like(out, ["1.png"], text="second")
    assert seen and not any(seen) and (out / "scene.ply").read_text() == "first"


def test_temporaries_beside_a_file_elsewhere_are_recognised_as_leftovers(tmp_path):
    """The staged manifest and the moved-away old file beside a video carry this process's
    owner mark, so a later run removes them if a kill left them."""
    out, videos = tmp_path / "out", tmp_path / "videos"
    names = []
    original = os.replace

    def spy(source, destination):
        names.extend(Path(p).name for p in (source, destination) if Path(p).parent == videos)
        original(source, destination)

    _restore_like(out, ["1.png"], video=videos / "orbit.mp4", text="first")
    os.replace = spy
    try:
        _restore_like(out, ["1.png"], video=videos / "orbit.mp4", text="second")
    finally:
        os.replace = original
    temporaries = [name for name in names if name.startswith(".") and name != MANIFEST_NAME]
    assert any("manifest" in name for name in temporaries) and any("replaced" in name for name in temporaries)
    assert all(atomic._OWNER.search(name) for name in temporaries), temporaries


def test_a_run_never_replaces_another_commands_output(tmp_path):
    """`render -o F` replaced the `degrade -o F/00000.png` there without a word, and a restore's
    --video the render's video of the same name: the docs promise other runs' outputs stay."""
    folder = tmp_path / "F"
    with OutputSet(folder, "degrade", "degrade 00000.png").add_file("00000.png").staged() as staging:
        (staging.root / "00000.png").write_text("degraded")
    with pytest.raises(InputError, match=r"F/00000.png: an output of another lumos3d command \(degrade, degrade 00000.png\)"):
        OutputSet(folder, "render", "render").add_file("00000.png").check()
    video = tmp_path / "videos" / "orbit.gif"
    video.parent.mkdir()
    render = OutputSet(tmp_path / "frames", "render", "render").add_file("00000.png")
    render.add_elsewhere(video, "video orbit.gif")
    with render.staged() as staging:
        (staging.root / "00000.png").write_text("frame")
        staging.files[video].write_text("rendered")
    with pytest.raises(InputError, match=r"orbit.gif: an output of another lumos3d command \(render, video orbit.gif\)"):
        _restore_like(tmp_path / "out", ["1.png"], video=video)
    assert video.read_text() == "rendered" and (folder / "00000.png").read_text() == "degraded"
    _restore_like(tmp_path / "out", ["1.png"], video=tmp_path / "videos" / "restored.gif")  # beside it: fine


def test_a_read_only_folder_the_run_replaces_is_refused_before_the_work(tmp_path, monkeypatch):
    """A read-only views/ failed only at the commit, after the whole job (os.access stands in
    for the permissions: the tests may run as root, who may write anywhere)."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png"], text="first")
    real = os.access
    monkeypatch.setattr(os, "access", lambda path, mode: False if Path(path) == out / "views" else real(path, mode))
    outputs = OutputSet(out, "restore", "restore scene.ply").add_file("scene.ply").add_file("summary.json").add_folder("views")
    with pytest.raises(InputError, match=r"out/views: is read-only, and this run replaces it"):
        outputs.check()


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_folders_that_take_no_files_are_refused_by_name():
    """`-o /proc/foo` ended in an internal FileNotFoundError; a lock in /sys was called "not
    lumos3d's lock file"."""
    with pytest.raises(InputError, match=r"^/proc/lumos3d-test/out: cannot be created \("):
        atomic.make_folders(Path("/proc/lumos3d-test/out"))
    with pytest.raises(InputError, match=r"^/proc: no file can be written there \("):
        with folder_lock(Path("/proc"), "render"):
            pass


def test_a_long_lived_process_finishes_a_commit_killed_since_it_last_wrote(tmp_path, monkeypatch):
    """A process (the Python API) that wrote into out once took the folder as cleaned for its
    life: another run's commit killed since was left unfinished under its next commit, and a
    later process replayed that stale journal over the newer set."""
    out, videos = tmp_path / "out", tmp_path / "videos"
    videos.mkdir()
    _restore_like(out, ["1.png"], text="first", video=videos / "orbit.mp4")  # `out` now counts as cleaned here
    with monkeypatch.context() as patch:
        patch.setattr(os, "getpid", lambda: 999999)  # another process, that has ended (no such pid here)
        assert _kill_mid_commit(out, monkeypatch, after=1, video=videos / "orbit.mp4", text="second")
    _restore_like(out, ["1.png"], text="third")  # this process again: the killed commit is finished first
    assert {(out / name).read_text() for name in ("scene.ply", "summary.json", "views/1.png")} == {"third"}
    assert (videos / "orbit.mp4").read_text() == "second"
    # and the killed run's temporaries in the video's folder (its marker, the old video) went with it
    assert hidden_entries(out) == [] and hidden_entries(videos) == []
    monkeypatch.setattr(atomic, "_cleaned", set())
    _restore_like(out, ["1.png"], text="fourth")  # a fresh process finds nothing to replay
    assert (out / "scene.ply").read_text() == "fourth"


def _acting_before_the_moves(monkeypatch, act):
    """Run `act` once, right before the commit's moves: after the last ownership check, in the
    moment a user's editor or another process could still write into the output folder."""
    original = output_set_module.write_commit_journal

    def journal_then_act(*args):
        original(*args)
        act()

    monkeypatch.setattr(output_set_module, "write_commit_journal", journal_then_act)


@pytest.mark.parametrize("change", ["added to a folder of outputs", "old output edited", "folder made", "video edited"])
def test_a_file_the_user_writes_between_the_last_check_and_the_moves_survives(tmp_path, monkeypatch, change):
    """The ownership check runs before the commit; a file written after it and before the moves was
    deleted with the old outputs (a new file in views/, or scene.ply edited). The old outputs are
    checked again where the commit moved them: such a commit is undone and refused."""
    out, video = tmp_path / "out", tmp_path / "videos" / "fly.mp4"
    video.parent.mkdir()
    _restore_like(out, ["1.png", "2.png"], text="first", video=video)

    def users_change():
        if change == "added to a folder of outputs":
            (out / "views" / "notes.txt").write_text("the user's")
        elif change == "old output edited":
            (out / "scene.ply").write_text("edited by the user")
        elif change == "video edited":
            video.write_text("cut by the user")
        else:
            (out / "views" / "mine").mkdir()

    _acting_before_the_moves(monkeypatch, users_change)
    place = {"added to a folder of outputs": "out/views/notes.txt", "old output edited": "out/scene.ply",
             "folder made": "out/views/mine", "video edited": "videos/fly.mp4"}[change]
    with pytest.raises(InputError, match=rf"{place}: changed or made while this run was committing its outputs.*"
                                         "nothing was changed"):
        _restore_like(out, ["1.png"], text="second", video=video)
    monkeypatch.undo()
    if change == "added to a folder of outputs":
        assert (out / "views" / "notes.txt").read_text() == "the user's"
    elif change == "old output edited":
        assert (out / "scene.ply").read_text() == "edited by the user"
    elif change == "video edited":
        assert video.read_text() == "cut by the user"
    else:
        assert (out / "views" / "mine").is_dir()
    assert sorted(os.listdir(video.parent)) == [MANIFEST_NAME, "fly.mp4"]
    assert [(out / "views" / name).read_text() for name in ("1.png", "2.png")] == ["first", "first"]
    assert (out / "summary.json").read_text() == "first" and hidden_entries(out) == []
    assert sorted(Manifest.read(out).files) == ["scene.ply", "summary.json", "views/1.png", "views/2.png"]


def test_a_run_that_begins_writing_inside_a_folder_of_outputs_during_the_commit_is_named(tmp_path, monkeypatch):
    """`render -o out/views` starting after the restore's last check and before its moves: its
    lock is checked where the commit moved the old views/, the commit undone and the run named."""
    out = tmp_path / "out"
    _restore_like(out, ["1.png"], text="first")
    holders = []

    def a_render_starts():
        holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
            import time
            from lumos3d_cli.io.output_set import OutputSet
            with OutputSet({str(out / "views")!r}, "render").add_file("00000.png").staged() as staging:
                print("staged", flush=True)
                time.sleep(60)
        """)], stdout=subprocess.PIPE, text=True)
        holders.append(holder)
        assert holder.stdout.readline().strip() == "staged"

    _acting_before_the_moves(monkeypatch, a_render_starts)
    try:
        with pytest.raises(InputError, match=rf"out/views: `lumos3d render`, process \d+ .* began writing its outputs "
                                             "here while this run was committing its own; nothing was changed"):
            _restore_like(out, ["1.png"], text="second")
        assert (out / "views" / "1.png").read_text() == "first" and (out / "scene.ply").read_text() == "first"
        assert LOCK_NAME in os.listdir(out / "views")  # the render's lock and staging stay where it made them
    finally:
        for holder in holders:
            holder.kill()
            holder.wait()


def test_a_rerun_reads_each_manifest_a_few_times_not_once_a_file(tmp_path, monkeypatch):
    """The ownership check read the folder's manifest again for every file it judged: a render of
    2,000 frames into the same folder again took 57 s for its checks (1.6 s reading it once)."""
    out = tmp_path / "out"
    names = [f"{index:05d}.png" for index in range(300)]

    def render_like():
        outputs = OutputSet(out, "render", "render")
        for name in names:
            outputs.add_file(name)
        with outputs.staged() as staging:
            for name in names:
                (staging.root / name).write_text(name)

    render_like()
    reads = []
    original = Manifest.read.__func__

    def counted(cls, folder):
        reads.append(folder)
        return original(cls, folder)

    monkeypatch.setattr(Manifest, "read", classmethod(counted))
    render_like()
    assert len(reads) < 20, len(reads)
