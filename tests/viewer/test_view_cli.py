import os
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request

import cv2
import numpy as np
import pytest

from assertions import expect_input_error


def _read_url(process: subprocess.Popen, timeout: float) -> str:
    """The first stdout line (the viewer prints its URL there once it serves)."""
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.append(process.stdout.readline()), daemon=True)
    reader.start()
    reader.join(timeout)
    if not lines or not lines[0].startswith("http://"):
        process.kill()
        raise AssertionError(f"no URL within {timeout} s: {lines!r}; stderr: {process.stderr.read()}")
    return lines[0].strip()


def _children(pid: int) -> list[int]:
    """Processes whose parent is `pid` (Linux /proc)."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as handle:
                    if int(handle.read().rsplit(")", 1)[1].split()[1]) == pid:
                        found.append(int(entry))
            except (OSError, IndexError, ValueError):
                continue
    return found


def test_view_serves_the_page_and_the_announced_subsample_then_stops_on_ctrl_c(restore_folder, viser_wire):
    process = subprocess.Popen(
        [sys.executable, "-m", "lumos3d_cli", "view", str(restore_folder), "--port", "0", "--max-splats", "200"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        url = _read_url(process, timeout=120)
        with urllib.request.urlopen(url, timeout=30) as response:
            assert response.status == 200 and b"<html" in response.read().lower()
        received = viser_wire.receive_scene(url)
        assert len(viser_wire.splats(received)) == 200
        assert "200 of 500 Gaussians" in viser_wire.markdown(received)
        assert _children(process.pid) == []
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, err
    assert "Traceback" not in err and "200 of 500 Gaussians" in err
    assert err.strip().splitlines()[-1] == "interrupted by SIGINT: the viewer stopped"
    port = int(url.rsplit(":", 1)[1])
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", port), timeout=5).close()


def test_view_bad_inputs(run_cli, restore_folder, tmp_path):
    expect_input_error(run_cli("view", tmp_path / "missing"), "missing: no such file or folder", "restore output folder")
    (tmp_path / "bad.ply").write_text("not a ply")
    expect_input_error(run_cli("view", tmp_path / "bad.ply", "--port", "0"), "bad.ply", "not a PLY file")
    (tmp_path / "notes.txt").write_text("hello")
    expect_input_error(run_cli("view", tmp_path / "notes.txt"), "notes.txt: not a .ply scene")
    empty = tmp_path / "empty"
    empty.mkdir()
    expect_input_error(run_cli("view", empty), "empty: no .ply scene in this folder")
    expect_input_error(run_cli("view", restore_folder, "--max-splats", "0"), "--max-splats 0")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        started = time.perf_counter()
        expect_input_error(run_cli("view", restore_folder, "--port", port), f"--port {port}: already in use", "--port")
        assert time.perf_counter() - started < 30
    # an address no interface of this machine has (TEST-NET-1, reserved for documentation) is the host's fault
    expect_input_error(run_cli("view", restore_folder, "--host", "192.0.2.1", "--port", "0"),
                       "--host 192.0.2.1: not an address of this machine")


def test_restore_with_view_refuses_a_bad_port_before_restoring(run_cli, tmp_path):
    """`restore --view` checks the port first: a port it cannot serve on writes no scene at all."""
    photos = tmp_path / "one-photo"
    photos.mkdir()
    cv2.imwrite(str(photos / "0.png"), np.random.default_rng(0).integers(0, 255, (96, 128, 3), dtype=np.uint8))
    output = tmp_path / "refused" / "scene.ply"
    expect_input_error(run_cli("restore", photos, "-o", output, "--view", "--port", "99999"), "--port 99999", "between 1 and 65535")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        expect_input_error(run_cli("restore", photos, "-o", output, "--view", "--port", port), f"--port {port}: already in use")
    # a port without --view would be ignored: refused, so the user learns the viewer was not asked for
    expect_input_error(run_cli("restore", photos, "-o", output, "--port", "8090"), "--port 8090", "add --view")
    assert not output.parent.exists()


def test_a_missing_viser_is_named_before_any_work(run_cli, restore_folder, tmp_path, monkeypatch):
    """Installed without its dependencies, the viewer ended in an internal error, and
    `restore --view` first restored the whole scene."""
    import importlib.util

    found = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *rest: None if name == "viser" else found(name, *rest))
    expect_input_error(run_cli("view", restore_folder, "--port", "0"), "the viewer needs viser", "pip install viser")
    photos = tmp_path / "one-photo"
    photos.mkdir()
    cv2.imwrite(str(photos / "0.png"), np.zeros((96, 128, 3), np.uint8))
    output = tmp_path / "refused" / "scene.ply"
    expect_input_error(run_cli("restore", photos, "-o", output, "--view", "--port", "0"), "the viewer needs viser")
    assert not output.parent.exists()
