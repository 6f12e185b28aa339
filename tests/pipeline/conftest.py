import shutil

import pytest



@pytest.fixture
def lom_copy(tmp_path, buu):
    """A writable copy of LOM buu (only what eval reads)."""
    target = tmp_path / "lom" / "buu"
    for folder in ("high", "low", "over_exp"):
        shutil.copytree(buu / folder, target / folder)
    for name in ("transforms_test.json", "transforms_train.json"):
        shutil.copy(buu / name, target / name)
    return target
