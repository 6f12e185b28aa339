"""Shared fixtures: the read-only data in ../shared/data and a CLI runner."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

if os.environ.get("PYTEST_XDIST_WORKER"):
    # `make test` runs one worker per core (pytest-xdist): each worker's torch and numba take one
    # thread, before torch is imported, or the workers' thread pools fight over the cores.
    os.environ.setdefault("OMP_NUM_THREADS", "1")

import pytest
import yaml

from lumos3d_cli.model.checkpoints import save_checkpoint
from lumos3d_cli.model.lumos3d import build_model

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("LUMOS3D_SHARED_DATA", REPO_ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data (override with LUMOS3D_SHARED_DATA)."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}; set LUMOS3D_SHARED_DATA")
    return SHARED_DATA


@pytest.fixture(scope="session")
def buu(shared_data: Path) -> Path:
    return shared_data / "lom" / "buu"


@pytest.fixture(scope="session")
def brackets(shared_data: Path) -> Path:
    """The shared SICE exposure brackets folder (skips, like shared_data, when it is absent)."""
    root = shared_data / "brackets"
    if not (root / "brackets.json").is_file():
        pytest.skip(f"no brackets at {root}")
    return root


@dataclass
class CliResult:
    code: int
    out: str
    err: str


@pytest.fixture
def run_cli(capsys):
    """Run `lumos3d ARGS...` in-process through the real entry point; returns code, stdout, stderr."""
    from lumos3d_cli.cli.app import main

    def run(*args) -> CliResult:
        capsys.readouterr()
        code = main([str(a) for a in args])
        captured = capsys.readouterr()
        return CliResult(code, captured.out, captured.err)

    return run


@pytest.fixture
def tiny_config(tmp_path, shared_data):
    """Write a small, fast training config and return its path; `changes` update it."""

    def make(stage="teacher", name="run", **changes):
        values = {
            "stage": stage,
            "output": str(tmp_path / name),
            "model": "tiny",
            "data": {"root": str(shared_data / "scenes"), "views": 2, "width": 56, "height": 42,
                     "scenes": ["video_fox", "statue", "llff_fern"]},
            "optim": {"steps": 6, "warmup_steps": 2},
            "log_every": 1,
            "checkpoint_every": 0,
        }
        for key, value in changes.items():
            section, _, field = key.partition("__")
            if field:
                values.setdefault(section, {})[field] = value
            else:
                values[key] = value
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(values))
        return path

    return make


@pytest.fixture(scope="session")
def random_checkpoint(tmp_path_factory):
    """A tiny model with random weights, saved in our format (tests only: it restores nothing)."""
    path = tmp_path_factory.mktemp("weights") / "tiny-random.safetensors"
    save_checkpoint(build_model("tiny", seed=0), path, {"weights": "random, for tests"})
    return path
