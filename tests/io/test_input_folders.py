import pytest

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.input_folders import require_folder


def test_a_file_given_for_a_folder_is_named_as_a_file(tmp_path):
    require_folder(tmp_path, "of scenes")
    (tmp_path / "README.md").write_text("not a folder")
    with pytest.raises(InputError, match=r"README.md: is a file, not a folder; give the folder of scenes"):
        require_folder(tmp_path / "README.md", "of scenes")
    with pytest.raises(InputError, match=r"missing: no such folder; give the folder of scenes"):
        require_folder(tmp_path / "missing", "of scenes")
