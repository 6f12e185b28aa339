"""The LOM reader on a small synthetic scene whose file names differ in case between folders (as
LOM's shrub does: `low/1.JPG`, `over_exp/1.jpg`)."""

import json

import cv2
import numpy as np
import pytest
import torch

from lumos3d_cli.data.lom import find_lom_scenes, lom_reference_extrinsics, read_lom_scene
from lumos3d_cli.errors import InputError

HIGH = ("IMG_1.JPG", "IMG_2.JPG", "IMG_10.JPG", "img_3.png")
LOW = ("img_1.jpg", "IMG_2.JPG", "Img_10.jpeg", "IMG_3.PNG")
OVER = ("IMG_1.jpg", "img_2.JPG", "img_10.jpg")  # view 3 has no over-exposed photo


def _frame(file_path: str, x: float) -> dict:
    matrix = np.eye(4)
    matrix[0, 3] = x
    return {"file_path": file_path, "transform_matrix": matrix.tolist()}


def _write(path, frames):
    path.write_text(json.dumps({"fl_x": 20.0, "fl_y": 20.0, "cx": 8.0, "cy": 6.0, "w": 16, "h": 12, "frames": frames}))


@pytest.fixture
def mixed_case_scene(tmp_path):
    scene = tmp_path / "lom" / "mixed"
    for folder, names in (("high", HIGH), ("low", LOW), ("over_exp", OVER)):
        (scene / folder).mkdir(parents=True)
        for index, name in enumerate(names):
            cv2.imwrite(str(scene / folder / name), np.full((12, 16, 3), 40 * index + 20, np.uint8))
    # the transforms files spell the names in yet another case
    _write(scene / "transforms_test.json", [_frame("high/img_2.jpg", 2.0)])
    _write(scene / "transforms_train.json", [_frame("high/img_1.jpg", 1.0), _frame("HIGH/Img_10.JPG", 10.0),
                                             _frame("high/IMG_3.png", 3.0)])
    return scene


def test_stems_match_case_insensitively(mixed_case_scene):
    low = read_lom_scene(mixed_case_scene, "low-light")
    assert low.frames == ["IMG_1", "IMG_2", "img_3", "IMG_10"]  # high/'s spelling, natural order
    assert low.test == ["IMG_2"]
    assert low.degraded["IMG_10"].name == "Img_10.jpeg" and low.reference["img_3"].name == "img_3.png"
    over = read_lom_scene(mixed_case_scene, "over-exposure")
    assert over.frames == ["IMG_1", "IMG_2", "IMG_10"] and over.test == ["IMG_2"]
    assert over.degraded["IMG_2"].name == "img_2.JPG"
    assert [s.name for s in find_lom_scenes(mixed_case_scene.parent, "over-exposure")] == ["mixed"]


def test_reference_cameras_use_the_frame_ids(mixed_case_scene):
    extrinsics = lom_reference_extrinsics(read_lom_scene(mixed_case_scene, "low-light"))
    assert set(extrinsics) == {"IMG_1", "IMG_2", "img_3", "IMG_10"}
    for frame, x in (("IMG_1", 1.0), ("IMG_2", 2.0), ("img_3", 3.0), ("IMG_10", 10.0)):
        # camera->world translation x along OpenGL x, which is OpenCV x: world->camera t = -x
        assert torch.allclose(extrinsics[frame][:, 3], torch.tensor([-x, 0.0, 0.0], dtype=torch.float64))


def test_missing_and_ambiguous_views(mixed_case_scene):
    _write(mixed_case_scene / "transforms_test.json", [_frame("high/img_3.png", 3.0)])
    with pytest.raises(InputError, match="test frame 'img_3' has no photo in over_exp/"):
        read_lom_scene(mixed_case_scene, "over-exposure")
    for frames, message in (([], "transforms_test.json: lists no test frames"),
                            ([{"transform_matrix": np.eye(4).tolist()}], "transforms_test.json: a frame without a file_path")):
        _write(mixed_case_scene / "transforms_test.json", frames)
        with pytest.raises(InputError, match=message):
            read_lom_scene(mixed_case_scene, "low-light")
    _write(mixed_case_scene / "transforms_test.json", [_frame("high/img_2.jpg", 2.0)])
    cv2.imwrite(str(mixed_case_scene / "low" / "IMG_1.png"), np.zeros((12, 16, 3), np.uint8))
    with pytest.raises(InputError, match="IMG_1.png and img_1.jpg are the same view"):
        read_lom_scene(mixed_case_scene, "low-light")


def test_a_frame_listed_twice_is_scored_once_and_unpaired_photos_are_named(mixed_case_scene, caplog):
    _write(mixed_case_scene / "transforms_test.json", [_frame("high/img_2.jpg", 2.0), _frame("high/IMG_10.JPG", 10.0),
                                                     _frame("high/IMG_2.JPG", 2.0)])
    scene = read_lom_scene(mixed_case_scene, "over-exposure")
    assert scene.test == ["IMG_2", "IMG_10"]
    assert "lists img_2 more than once" in caplog.text
    # view 3 has no over-exposed photo: the scene goes on without it, and says so
    assert "3" not in scene.frames and "high/img_3.png has no photo in over_exp/" in caplog.text
    caplog.clear()
    read_lom_scene(mixed_case_scene, "low-light")
    assert "no photo" not in caplog.text


def test_a_scene_name_as_a_shell_completes_it(mixed_case_scene):
    assert [scene.name for scene in find_lom_scenes(mixed_case_scene.parent, "low-light", ["mixed/", "./mixed", "mixed"])] == ["mixed"]


def test_shrub_reads_in_both_modes(shared_data):
    shrub = shared_data / "lom" / "shrub"
    if not shrub.is_dir():
        pytest.skip("no LOM shrub in the shared data")
    for mode in ("low-light", "over-exposure"):
        scene = read_lom_scene(shrub, mode)
        assert len(scene.frames) == 35 and scene.test == ["1", "17", "24", "31", "7"]
        assert set(lom_reference_extrinsics(scene)) == set(scene.frames)


def test_one_name_is_a_scene_and_no_names_are_refused(mixed_case_scene):
    root = mixed_case_scene.parent
    assert [scene.name for scene in find_lom_scenes(root, "low-light", "mixed")] == ["mixed"]  # not "m", "i", ...
    assert [scene.name for scene in find_lom_scenes(root, "low-light", None)] == ["mixed"]
    with pytest.raises(InputError, match="^scenes \\[\\]: name at least one scene"):
        find_lom_scenes(root, "low-light", [])


def test_a_scene_given_as_dot_or_dotdot_is_named_after_its_folder(mixed_case_scene, monkeypatch):
    """`eval .` named the scene "" (contact_sheet_.png, an empty scene column) and `eval ..` "..". """
    monkeypatch.chdir(mixed_case_scene)
    assert [scene.name for scene in find_lom_scenes(".", "low-light")] == ["mixed"]
    monkeypatch.chdir(mixed_case_scene / "high")
    assert [scene.name for scene in find_lom_scenes("..", "low-light")] == ["mixed"]


@pytest.mark.parametrize("frames", [5, [5], [{"file_path": 5}], "high/img_2.jpg"])
def test_test_frames_of_the_wrong_kind_are_named(mixed_case_scene, frames):
    """`"frames": 5` was reported as "a frame without a file_path ('int' object is not iterable)"."""
    _write(mixed_case_scene / "transforms_test.json", frames)
    with pytest.raises(InputError, match="transforms_test.json: (\"frames\" must be a list of objects|a frame's file_path "
                                         "is not a path)"):
        read_lom_scene(mixed_case_scene, "low-light")
