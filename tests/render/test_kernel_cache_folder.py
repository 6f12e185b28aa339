"""Where numba caches the kernels when neither the package nor the user's cache can be written
(render/kernels/cache_folder.py): a per-user folder of the temporary directory."""

import os
import subprocess
import sys
import tempfile
from pathlib import Path

from lumos3d_cli.render.kernels.cache_folder import fallback_cache_folder, private_temporary_folder, writable

KERNELS = Path("/site-packages/lumos3d_cli/render/kernels")


def test_numba_keeps_its_choice_where_it_can_write():
    assert fallback_cache_folder(KERNELS, {"NUMBA_CACHE_DIR": "/x"}, lambda _: False) is None
    assert fallback_cache_folder(KERNELS, {}, lambda folder: folder == KERNELS / "__pycache__") is None
    user = Path("/home/u/.cache/numba")
    assert fallback_cache_folder(KERNELS, {"HOME": "/home/u"}, lambda folder: folder == user) is None
    xdg = Path("/xdg/numba")
    assert fallback_cache_folder(KERNELS, {"HOME": "/home/u", "XDG_CACHE_HOME": "/xdg"}, lambda f: f == xdg) is None


def test_a_read_only_install_without_a_home_caches_in_a_private_temporary_folder(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    folder = fallback_cache_folder(KERNELS, {"HOME": "/nonexistent"}, lambda _: False)
    assert folder == tmp_path / f"lumos3d-numba-{os.getuid()}"
    assert folder.is_dir() and folder.stat().st_mode & 0o777 == 0o700


def test_a_temporary_folder_others_could_have_planted_is_never_used(tmp_path, monkeypatch):
    """numba unpickles what it finds there: a folder open to others, or a file in its place, is
    passed over for a fresh private one."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    shared = tmp_path / f"lumos3d-numba-{os.getuid()}"
    shared.mkdir(mode=0o777)
    shared.chmod(0o777)
    folder = private_temporary_folder()
    assert folder != shared and folder.parent == tmp_path and folder.stat().st_mode & 0o777 == 0o700
    shared.rmdir()
    shared.write_text("not a folder")
    assert private_temporary_folder() not in (shared, folder)


def test_writable_looks_at_the_nearest_existing_folder(tmp_path):
    assert writable(tmp_path / "not" / "yet")  # created by numba under a writable folder
    (tmp_path / "file").write_text("x")
    assert not writable(tmp_path / "file")  # a file is no folder
    assert not writable(tmp_path / "file" / "below")


def test_the_kernels_follow_the_fallback_when_it_applies(tmp_path):
    """In a fresh process whose NUMBA_CACHE_DIR is unset, numba's cache folder is the fallback's
    exactly when the fallback applies (here: never on a writable checkout, so numba's default)."""
    environment = {key: value for key, value in os.environ.items() if key != "NUMBA_CACHE_DIR"}
    code = ("import numba, lumos3d_cli.render.kernels as k; "
            "print(repr(k._FALLBACK), repr(numba.config.CACHE_DIR))")
    out = subprocess.run([sys.executable, "-c", code], env=environment, capture_output=True, text=True, check=True).stdout
    fallback, cache_dir = out.strip().split(" ", 1)
    assert (fallback == "None") == (cache_dir == "''"), out
