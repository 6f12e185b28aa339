"""io/image_files.py: the same photo twice is refused, naming both; what a folder listing skips."""

import logging
import os

import cv2
import numpy as np
import pytest

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.image_files import list_images


@pytest.fixture
def folders(tmp_path):
    for folder, names in (("a", ["1.jpg", "2.jpg"]), ("b", ["1.jpg"]), ("c", ["IMG_1.png", "IMG_1.jpg"])):
        (tmp_path / folder).mkdir()
        for name in names:
            cv2.imwrite(str(tmp_path / folder / name), np.zeros((4, 4, 3), np.uint8))
    return tmp_path


def test_the_same_file_twice_is_refused(folders):
    with pytest.raises(InputError, match=r"a/1\.jpg: the same photo is given twice"):
        list_images([folders / "a", folders / "a" / "1.jpg"])
    with pytest.raises(InputError, match="given twice"):
        list_images([folders / "a" / "2.jpg", folders / "b" / ".." / "a" / "2.jpg"])


def test_two_files_with_one_name_are_refused(folders):
    with pytest.raises(InputError, match=r"a/1\.jpg and .*b/1\.jpg: two photos named '1'"):
        list_images([folders / "a", folders / "b"])
    with pytest.raises(InputError, match=r"two photos named 'IMG_1'"):  # a camera's RAW+JPEG pair, say
        list_images(folders / "c")
    assert [p.name for p in list_images([folders / "a", folders / "c" / "IMG_1.png"])] == ["1.jpg", "2.jpg", "IMG_1.png"]
    # names that differ in case alone: one view's outputs (restored/a.png) on a case-insensitive disk,
    # and one pose for both (poses match stems in any case)
    (folders / "d").mkdir()
    for name in ("A.jpg", "a.png"):
        (folders / "d" / name).write_bytes((folders / "a" / "1.jpg").read_bytes())
    with pytest.raises(InputError, match=r"two photos named 'a'"):
        list_images(folders / "d")


def test_entries_named_as_images_that_are_not_files_are_skipped_by_name(tmp_path, caplog):
    (tmp_path / "1.jpg").write_bytes(b"x")
    (tmp_path / "2.jpg").symlink_to(tmp_path / "gone.jpg")  # a broken link
    os.mkfifo(tmp_path / "3.png")
    with caplog.at_level(logging.WARNING, logger="lumos3d_cli.io.image_files"):
        assert list_images(tmp_path) == [tmp_path / "1.jpg"]
    assert "skipped 2.jpg, 3.png" in caplog.text
    with pytest.raises(InputError, match="3.png: is not a file"):
        list_images(tmp_path / "3.png")
    with pytest.raises(InputError, match="2.jpg: no such file or folder"):
        list_images(tmp_path / "2.jpg")


def test_images_in_formats_lumos3d_does_not_read_are_named_when_skipped(tmp_path, caplog):
    for name in ("IMG_2.HEIC", "IMG_10.avif", "IMG_3.gif"):
        (tmp_path / name).write_bytes(b"x")
    (tmp_path / "notes.txt").write_text("not an image: skipped silently")
    with pytest.raises(InputError, match="holds no images .*; IMG_2.HEIC, IMG_3.gif, IMG_10.avif cannot be read: convert"):
        list_images(tmp_path)
    (tmp_path / "IMG_1.jpg").write_bytes(b"x")
    with caplog.at_level(logging.WARNING, logger="lumos3d_cli.io.image_files"):
        assert list_images(tmp_path) == [tmp_path / "IMG_1.jpg"]
    assert "skipped IMG_2.HEIC, IMG_3.gif, IMG_10.avif: a format lumos3d does not read" in caplog.text
    assert "notes.txt" not in caplog.text


def test_a_file_name_that_is_not_utf8_is_refused_naming_the_file(folders):
    """A Latin-1 `café.jpg` ended in an internal error from OpenImageIO, which takes names as text."""
    name = os.fsdecode(b"caf\xe9.jpg")
    (folders / "a" / name).write_bytes((folders / "a" / "1.jpg").read_bytes())
    for given in (folders / "a", folders / "a" / name):
        with pytest.raises(InputError, match=r"a/caf\\xe9\.jpg: the file name is not UTF-8 text.*rename the file"):
            list_images(given)
