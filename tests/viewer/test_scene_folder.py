import json
import shutil

import pytest

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.ply import write_ply
from lumos3d_cli.viewer.scene_folder import load_viewer_scene, thumbnail

from factories import random_scene


def test_a_restore_folder_gives_everything(restore_folder):
    scene = load_viewer_scene(restore_folder)
    assert scene.scene_path.name == "scene.ply" and len(scene.gaussians) == 500
    assert len(scene.cameras) == 3 and len(scene.points.xyz) == 4 and scene.summary["mode"] == "low-light"
    assert all(image.shape == (30, 40, 3) for image in scene.restored + scene.inputs)
    assert scene.notes == []
    # The .ply named inside its folder is read with the folder.
    assert load_viewer_scene(restore_folder / "scene.ply").cameras is not None


def test_missing_pieces_become_notes(restore_folder, tmp_path):
    summary = json.loads((restore_folder / "summary.json").read_text())
    del summary["input_paths"]
    (restore_folder / "summary.json").write_text(json.dumps(summary))
    (restore_folder / "restored" / "photo1.png").unlink()
    scene = load_viewer_scene(restore_folder)
    assert scene.inputs == [None] * 3 and scene.restored[1] is None
    assert any("does not list their paths" in note for note in scene.notes)
    assert any("1 of 3 missing" in note for note in scene.notes)


def test_photos_that_cannot_be_read_are_left_out_with_a_note(restore_folder, caplog):
    """A damaged original photo (the user's, outside the folder) or restored view refused the whole
    viewer, telling the user to remove their photo; a missing one was a note."""
    summary = json.loads((restore_folder / "summary.json").read_text())
    damaged = summary["input_paths"][0]
    with open(damaged, "w") as photo:
        photo.write("garbage")
    (restore_folder / "restored" / "photo2.png").write_bytes(b"not a png")
    scene = load_viewer_scene(restore_folder)
    assert scene.inputs[0] is None and scene.inputs[1] is not None and scene.restored[2] is None
    assert "photos: 2 could not be read" in " ".join(scene.notes)
    assert f"{damaged}: cannot decode" in caplog.text


def test_an_empty_scene_is_refused_and_a_bare_ply_is_shown_whatever_lies_beside_it(tmp_path, caplog):
    """The viewer served an empty scene without a word (render refuses it); a broken summary.json
    beside a bare .ply refused it, advising to pass the .ply alone, which had been done."""
    write_ply(tmp_path / "empty.ply", random_scene(0, 0, degree=0))
    with pytest.raises(InputError, match="empty.ply: holds no Gaussians; there is nothing to view"):
        load_viewer_scene(tmp_path / "empty.ply")
    write_ply(tmp_path / "a.ply", random_scene(20, 0, degree=0))
    (tmp_path / "summary.json").write_text("{bad")
    scene = load_viewer_scene(tmp_path / "a.ply")
    assert len(scene.gaussians) == 20 and "bare .ply" in scene.notes[0]
    assert "summary.json: not readable JSON" in caplog.text


def test_a_bare_ply(tmp_path):
    write_ply(tmp_path / "a.ply", random_scene(20, 0, degree=0))
    scene = load_viewer_scene(tmp_path / "a.ply")
    assert len(scene.gaussians) == 20 and scene.cameras is None and scene.summary is None
    assert scene.notes and "bare .ply" in scene.notes[0]


def test_folder_errors(restore_folder, tmp_path):
    shutil.copy(restore_folder / "scene.ply", restore_folder / "other.ply")
    (restore_folder / "summary.json").unlink()
    with pytest.raises(InputError, match=r"2 \.ply files \(other\.ply, scene\.ply\); pass the one to view"):
        load_viewer_scene(restore_folder)
    (restore_folder / "summary.json").write_text("{broken")
    with pytest.raises(InputError, match="summary.json: not readable JSON"):
        load_viewer_scene(restore_folder)


def test_thumbnails_are_small(tmp_path):
    import numpy as np

    from lumos3d_cli.io.image_write import write_image

    write_image(tmp_path / "big.png", np.full((700, 1000, 3), 0.5, np.float32))
    assert thumbnail(tmp_path / "big.png").shape == (224, 320, 3)
