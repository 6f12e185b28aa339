"""Start-up (issue 37): `lumos3d --version`, `--help` and every command's `--help` answer without
importing the libraries that take seconds to import; each command imports them when it runs.
Checked by what the child process imports (`python -X importtime`), never by the clock, which a
loaded machine would make flaky; benchmarks/startup.py measures the times."""

import json
import subprocess
import sys

import pytest

from lumos3d_cli.cli.app import _COMMAND_PANELS
from lumos3d_cli.io.ply import write_ply

from factories import random_gaussians

# Each takes from a tenth of a second (numpy, imageio-ffmpeg) to seconds (torch, pycolmap) to import.
HEAVY = ("torch", "numpy", "pycolmap", "trimesh", "viser", "imageio_ffmpeg", "cv2", "numba", "OpenImageIO", "rawpy",
         "safetensors")
COMMAND_LINES = [("--version",), ("--help",), *((name, "--help") for name in _COMMAND_PANELS)]


def imported_modules(*args: str) -> tuple[subprocess.CompletedProcess, set[str]]:
    """Run `python -m lumos3d_cli ARGS` (what the `lumos3d` script runs); the modules it imported."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "lumos3d_cli", *args],
                          capture_output=True, text=True, timeout=120)
    modules = {line.rsplit("|", 1)[1].strip() for line in done.stderr.splitlines() if line.startswith("import time:")}
    modules.discard("package")  # the header line: "import time: self [us] | cumulative | imported package"
    return done, modules


@pytest.mark.parametrize("args", COMMAND_LINES, ids=" ".join)
def test_help_and_version_import_none_of_the_heavy_libraries(args):
    done, modules = imported_modules(*args)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "lumos3d" in done.stdout  # the version line or the usage
    assert "lumos3d_cli.cli.app" in modules  # the probe sees the imports
    assert sorted({name.split(".")[0] for name in modules} & set(HEAVY)) == []


def test_version_imports_no_subcommand():
    done, modules = imported_modules("--version")
    assert done.returncode == 0 and done.stdout.startswith("lumos3d ")
    assert sorted(m for m in modules if m.removeprefix("lumos3d_cli.cli.") in _COMMAND_PANELS) == []


def test_a_command_that_runs_imports_the_library(tmp_path):
    # The other side of the lazy imports: `info` of a scene reads it with torch, inside the command.
    write_ply(tmp_path / "scene.ply", random_gaussians(10, 0))
    done, modules = imported_modules("info", str(tmp_path / "scene.ply"), "--json")
    assert done.returncode == 0, done.stderr[-3000:]
    assert json.loads(done.stdout)["count"] == 10
    assert {"torch", "lumos3d_cli.io.summaries"} <= modules


def test_restore_and_degrade_refuse_their_own_photo_folder_before_importing_the_library(tmp_path, buu):
    # A refusal of the paths needs no library: it ends at once (0.3 s against 2 s with torch).
    for name in ("1.JPG", "2.JPG"):
        (tmp_path / name).write_bytes((buu / "low" / name).read_bytes())
    for args in (("restore", str(tmp_path), "-o", str(tmp_path / "scene.ply")),
                 ("degrade", str(tmp_path), "-o", str(tmp_path))):
        done, modules = imported_modules(*args)
        assert done.returncode == 2 and "is the input folder" in done.stderr, done.stderr[-3000:]
        assert sorted({name.split(".")[0] for name in modules} & set(HEAVY)) == []
    assert sorted(path.name for path in tmp_path.iterdir()) == ["1.JPG", "2.JPG"]


def test_eval_and_convert_refuse_a_users_file_before_importing_the_library(tmp_path):
    write_ply(tmp_path / "scene.ply", random_gaussians(10, 0))
    (tmp_path / "report").mkdir()
    (tmp_path / "report" / "metrics.json").write_text("the user's")
    (tmp_path / "mine.splat").write_text("the user's")
    (tmp_path / "lom").mkdir()
    for args in (("eval", str(tmp_path / "lom"), "--out", str(tmp_path / "report")),
                 ("convert", str(tmp_path / "scene.ply"), "-o", str(tmp_path / "mine.splat"))):
        done, modules = imported_modules(*args)
        assert done.returncode == 2 and "exists and was not written by lumos3d" in done.stderr, done.stderr[-3000:]
        assert sorted({name.split(".")[0] for name in modules} & set(HEAVY)) == []
    assert (tmp_path / "report" / "metrics.json").read_text() == (tmp_path / "mine.splat").read_text() == "the user's"


# pycolmap's logging library installs its own SIGTERM handler (print a stack dump, abort) when it is
# first imported, which is now inside a command, after the CLI installed its handlers.
_SIGNAL_AFTER_IMPORTS = """
import os, signal
from lumos3d_cli.cli.interrupts import library_imports, signals_raise_interrupted
from lumos3d_cli.errors import Interrupted
try:
    with signals_raise_interrupted():
        with library_imports():
            import pycolmap
        os.kill(os.getpid(), signal.SIGTERM)
        signal.pause()
except Interrupted as stop:
    print(stop.signal_name)
"""


def test_the_cli_claims_the_signals_back_from_a_library_imported_by_a_command():
    done = subprocess.run([sys.executable, "-c", _SIGNAL_AFTER_IMPORTS], capture_output=True, text=True, timeout=120)
    assert (done.returncode, done.stdout.strip()) == (0, "SIGTERM"), done.stderr[-3000:]


# A signal that lands while the library is being imported (after pycolmap put in its own handler,
# before the CLI's are back) waits for the CLI's handler instead of reaching pycolmap's stack dump.
_SIGNAL_DURING_IMPORTS = """
import os, signal
from lumos3d_cli.cli.interrupts import library_imports, signals_raise_interrupted
from lumos3d_cli.errors import Interrupted
try:
    with signals_raise_interrupted():
        with library_imports():
            import pycolmap
            os.kill(os.getpid(), signal.SIGTERM)
            print("imports went on")
        signal.pause()
except Interrupted as stop:
    print(stop.signal_name)
"""


def test_a_signal_during_the_imports_is_held_for_the_clis_handler():
    done = subprocess.run([sys.executable, "-c", _SIGNAL_DURING_IMPORTS], capture_output=True, text=True, timeout=120)
    assert (done.returncode, done.stdout.split()) == (0, ["imports", "went", "on", "SIGTERM"]), done.stderr[-3000:]
    assert "stack trace" not in done.stderr and "Aborted" not in done.stderr


@pytest.mark.parametrize("chosen", [None, "ACTIVE"])
def test_importing_the_package_asks_openmp_to_sleep_unless_the_user_chose(chosen):
    """OpenMP's wait policy is read when torch starts its threads: importing lumos3d_cli (before
    torch, as the command line and the README's snippets do) sets it, and leaves a choice alone."""
    import os

    environment = {key: value for key, value in os.environ.items() if key != "OMP_WAIT_POLICY"}
    if chosen is not None:
        environment["OMP_WAIT_POLICY"] = chosen
    code = "import lumos3d_cli, os; print(os.environ['OMP_WAIT_POLICY'])"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environment, check=True)
    assert done.stdout.strip() == (chosen or "PASSIVE")
