"""The commit is one step (issue 38, rows 6-7): with every rename of the commit slowed down (a
monkeypatched os.replace in the child process), a signal during the commit leaves the complete
new output set, a second run into the same folder is refused instead of interleaving, and a
signal while the video is written leaves the complete old set, video included."""

import json
import shutil
import signal
import subprocess
import sys
import time

from lumos3d_cli.io.manifest import Manifest

from assertions import expect_input_error
from output_files import copy_photos, restore_args, snapshot
from processes import hidden_entries, interrupt_when, run_lumos3d

# The child: os.replace slowed down for the moves of a commit (source and destination on
# different sides of the staging folder), not for the writers' own renames inside it; or, with a
# gate file, each such move waits until the test creates that file (and the child says it waits
# by creating GATE.waiting).
_SLOW_COMMIT = """
import os, sys, time
from pathlib import Path
from lumos3d_cli.cli.app import main
delay, gate, replace = float(sys.argv[1]), sys.argv[2], os.replace
def slow(source, destination, **kwargs):
    if (".staging." in str(source)) != (".staging." in str(destination)) or ".replaced" in str(destination):
        time.sleep(delay)
        if gate and not Path(gate).exists():
            Path(gate + ".waiting").touch()  # the test may now act during the commit
            while not Path(gate).exists():
                time.sleep(0.02)
    return replace(source, destination, **kwargs)
os.replace = slow
sys.exit(main(sys.argv[3:]))
"""


def _slow_commit(delay, *args, gate=""):
    """`lumos3d ARGS` with each rename of its commit `delay` seconds long and, with `gate`, held
    until that file exists."""
    return subprocess.Popen([sys.executable, "-c", _SLOW_COMMIT, str(delay), str(gate), *(str(a) for a in args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _committing(out):
    return any(out.glob(".staging.*/.commit.json"))


def _consistent(out, names):
    """Every output of the restore holds the views `names`, and the manifest is the folder's."""
    summary = json.loads((out / "summary.json").read_text())
    cameras = json.loads((out / "cameras.json").read_text())
    images = (out / "colmap" / "images.txt").read_text()
    assert summary["views"] == names and len(cameras["frames"]) == len(names)
    assert sorted(p.stem for p in (out / "restored").iterdir()) == sorted(name.split(".")[0] for name in names)
    assert all(name in images for name in names)
    manifest = Manifest.read(out)
    files = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file() and not p.name.startswith(".")}
    assert set(manifest.files) == files and all(manifest.owns(out / name) for name in files)
    assert hidden_entries(out) == []


def test_row6_a_signal_during_the_renames_leaves_the_complete_new_set(tmp_path, buu, random_checkpoint, earlier_restore):
    out = shutil.copytree(earlier_restore, tmp_path / "out")
    fewer = copy_photos(buu, tmp_path / "fewer", ["2.JPG", "4.JPG", "6.JPG"])
    gate = tmp_path / "signal-sent"
    process = _slow_commit(0.0, *restore_args(fewer, out / "scene.ply", random_checkpoint), gate=gate)
    try:
        deadline = time.monotonic() + 600
        while not (tmp_path / "signal-sent.waiting").exists():  # the commit holds at its first rename
            assert process.poll() is None and time.monotonic() < deadline, process.communicate()[1][-3000:]
            time.sleep(0.02)
        assert _committing(out)
        process.send_signal(signal.SIGTERM)
        time.sleep(0.2)
        gate.touch()
        out_text, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 143, err[-3000:]
    assert err.strip().splitlines()[-1].startswith("interrupted by SIGTERM: after the outputs were written"), err
    _consistent(out, ["2.JPG", "4.JPG", "6.JPG"])


def test_row6_a_second_run_into_the_same_folder_is_refused_naming_the_first(tmp_path, buu, random_checkpoint, earlier_restore):
    out = shutil.copytree(earlier_restore, tmp_path / "out")
    # the first run's commit waits at its first rename until the second run has come and gone
    gate = tmp_path / "second-run-done"
    first = _slow_commit(0.0, *restore_args(copy_photos(buu, tmp_path / "first", ["1.JPG", "2.JPG", "3.JPG"]),
                                            out / "scene.ply", random_checkpoint), gate=gate)
    try:
        deadline = time.monotonic() + 600
        while not _committing(out):
            assert first.poll() is None and time.monotonic() < deadline, first.communicate()[1][-3000:]
            time.sleep(0.02)
        second = run_lumos3d(*restore_args(copy_photos(buu, tmp_path / "second", ["4.JPG", "5.JPG"]),
                                           out / "scene.ply", random_checkpoint))
        gate.touch()
        _, err = first.communicate(timeout=300)
    finally:
        if first.poll() is None:
            first.kill()
    expect_input_error(second, f"{out}: `lumos3d restore`, process {first.pid}", "is writing its outputs here")
    assert first.returncode == 0, err[-3000:]
    _consistent(out, ["1.JPG", "2.JPG", "3.JPG"])


def _video_started(folder):
    return any(p.stat().st_size > 0 for p in folder.glob(".orbit.*.tmp.mp4"))


def test_row7_a_signal_while_the_video_is_written_leaves_the_old_set_with_its_video(tmp_path, buu, random_checkpoint):
    photos = copy_photos(buu, tmp_path / "photos", ["1.JPG", "2.JPG", "3.JPG"])
    out = tmp_path / "out"
    first = run_lumos3d(*restore_args(photos, out / "scene.ply", random_checkpoint, "--video", out / "orbit.mp4"))
    assert first.code == 0, first.err
    before = snapshot(out)
    stopped = interrupt_when(restore_args(copy_photos(buu, tmp_path / "new", ["4.JPG", "5.JPG"]), out / "scene.ply",
                                          random_checkpoint, "--video", out / "orbit.mp4"),
                             lambda _: _video_started(out), signal.SIGTERM)
    assert stopped.code == 143, stopped.err[-3000:]
    assert stopped.last_line == "interrupted by SIGTERM; nothing half-written was left behind"
    assert snapshot(out) == before


def test_row7_render_never_pairs_a_new_video_with_old_frames(tmp_path, earlier_restore):
    scene = earlier_restore / "scene.ply"
    args = ("render", scene, "--orbit", 4, "-o", tmp_path / "frames", "--width", 48, "--video", tmp_path / "orbit.mp4")
    assert run_lumos3d(*args).code == 0
    before = snapshot(tmp_path)
    stopped = interrupt_when(("render", scene, "--orbit", 5000, "-o", tmp_path / "frames", "--width", 48,
                              "--video", tmp_path / "orbit.mp4"), lambda _: _video_started(tmp_path), signal.SIGTERM)
    assert stopped.code == 143, stopped.err[-3000:]
    assert snapshot(tmp_path) == before
    fewer = run_lumos3d("render", scene, "--orbit", 2, "-o", tmp_path / "frames", "--width", 48)
    assert fewer.code == 0, fewer.err
    assert sorted(p.name for p in (tmp_path / "frames").iterdir() if not p.name.startswith(".")) == ["00000.png", "00001.png"]
    assert (tmp_path / "orbit.mp4").read_bytes() == before["orbit.mp4"]  # a video of its own set: kept

