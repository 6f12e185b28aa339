import shutil

import pytest

from lumos3d_cli.model.checkpoints import save_checkpoint
from lumos3d_cli.model.lumos3d import build_model


@pytest.fixture(scope="session")
def random_checkpoint(tmp_path_factory):
    """A tiny model with random weights, saved in our format (tests only: it restores nothing)."""
    path = tmp_path_factory.mktemp("weights") / "tiny-random.safetensors"
    save_checkpoint(build_model("tiny", seed=0), path, {"weights": "random, for tests"})
    return path


@pytest.fixture
def lom_copy(tmp_path, buu):
    """A writable copy of LOM buu (only what eval reads)."""
    target = tmp_path / "lom" / "buu"
    for folder in ("high", "low", "over_exp"):
        shutil.copytree(buu / folder, target / folder)
    for name in ("transforms_test.json", "transforms_train.json"):
        shutil.copy(buu / name, target / name)
    return target
