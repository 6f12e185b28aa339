"""Fixtures of the data-safety tests (with the tiny random model of tests/conftest.py: the tests are
about files, not restoration): one earlier restore to run into again, a file that is no
checkpoint."""

import pytest

from output_files import copy_photos, restore_args
from processes import run_lumos3d


@pytest.fixture(scope="session")
def earlier_restore(tmp_path_factory, buu, random_checkpoint):
    """The outputs of one restore of six photos (copy it before changing it)."""
    photos = copy_photos(buu, tmp_path_factory.mktemp("earlier") / "photos")
    out = tmp_path_factory.mktemp("earlier-out") / "out"
    result = run_lumos3d(*restore_args(photos, out / "scene.ply", random_checkpoint))
    assert result.code == 0, result.err
    return out


@pytest.fixture(scope="session")
def garbage_checkpoint(tmp_path_factory):
    """Not a checkpoint: the first thing to fail once a restore's work starts, so a refusal that
    names something else came before the work."""
    path = tmp_path_factory.mktemp("garbage") / "garbage.safetensors"
    path.write_bytes(b"not a checkpoint")
    return path
