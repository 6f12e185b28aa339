"""io/output_paths.py: an output that cannot be written is refused up front, naming it."""

import os

import pytest

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.output_paths import check_output_path


def test_writable_outputs_pass(tmp_path):
    check_output_path(tmp_path / "new" / "deeper" / "scene.ply", "output")
    check_output_path(tmp_path, "output", folder=True)
    check_output_path(None, "video")
    (tmp_path / "old.ply").write_text("replaced by the run")
    check_output_path(tmp_path / "old.ply", "output")


def test_unwritable_outputs_are_refused_naming_the_parameter_and_path(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match=r"^video .*/file/a/b\.mp4: cannot be created because .*/file is a file"):
        check_output_path(tmp_path / "file" / "a" / "b.mp4", "video")
    with pytest.raises(InputError, match=r"^output .*/file: is a file; give a folder here"):
        check_output_path(tmp_path / "file", "output", folder=True)
    with pytest.raises(InputError, match=r"^output .*: is a folder; give a file here"):
        check_output_path(tmp_path, "output")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes anywhere")
def test_a_read_only_folder_is_refused(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    with pytest.raises(InputError, match="no permission to write in"):
        check_output_path(locked / "scene.ply", "output")
