import logging
import shutil

import pytest
import torch

from lumos3d_cli.data.lom import lom_reference_extrinsics, read_lom_scene
from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.given_poses import read_given_poses
from lumos3d_cli.io.colmap import read_colmap_model, write_colmap_model
from lumos3d_cli.io.transforms_json import write_transforms_json

from synthetic_scene import plane_cameras


def _named(cameras, names):
    cameras.names = names
    return cameras


def test_buu_transforms_reproduce_the_dataset_cameras(buu, caplog):
    scene = read_lom_scene(buu, "low-light")
    names = [scene.degraded[frame].name for frame in scene.frames]
    with caplog.at_level(logging.WARNING):
        cameras = read_given_poses(buu, names, [(500, 375)] * len(names))
    # buu's cameras are distorted: taken as pinhole ones, said once (not once per split file)
    assert caplog.text.count("distortion") == 1
    caplog.clear()
    read_given_poses(buu, names, [(500, 375)] * len(names), warn_on_distortion=False)
    assert "distortion" not in caplog.text
    reference = lom_reference_extrinsics(scene)
    assert cameras.names == names and cameras.sizes == [(500, 375)] * 25
    torch.testing.assert_close(cameras.extrinsics, torch.stack([reference[f] for f in scene.frames]), atol=0, rtol=0)
    # a photo at half the resolution of the poses' images gets half the focal length
    halved = read_given_poses(buu, names, [(250, 188)] * len(names))
    torch.testing.assert_close(halved.intrinsics[:, 0], cameras.intrinsics[:, 0] / 2)
    torch.testing.assert_close(halved.intrinsics[:, 1], cameras.intrinsics[:, 1] * 188 / 375)


def test_binary_and_text_colmap_models_agree_and_are_rescaled(buu):
    text = read_colmap_model(buu / "colmap_text")
    names = list(text.names)
    binary = read_given_poses(buu / "colmap_sparse" / "0", names, text.sizes)
    torch.testing.assert_close(binary.extrinsics, text.extrinsics, atol=1e-12, rtol=0)
    torch.testing.assert_close(binary.intrinsics, text.intrinsics, atol=1e-12, rtol=0)
    width, height = text.sizes[0]
    small = read_given_poses(buu / "colmap_sparse" / "0", [n.replace(".JPG", ".png") for n in names], [(width // 2, height // 2)] * 25)
    torch.testing.assert_close(small.intrinsics, text.rescaled(width // 2, height // 2).intrinsics, atol=1e-9, rtol=0)


def test_photos_match_poses_by_stem_in_photo_order(tmp_path):
    cameras = _named(plane_cameras(4), ["images/c.jpg", "images/a.jpg", "images/d.jpg", "images/b.jpg"])
    write_transforms_json(tmp_path / "transforms.json", cameras)
    write_colmap_model(tmp_path / "sparse" / "0", cameras)
    for source in (tmp_path / "transforms.json", tmp_path / "sparse" / "0"):
        given = read_given_poses(source, ["a.png", "b.png", "c.png", "d.png"], [cameras.sizes[0]] * 4)
        torch.testing.assert_close(given.extrinsics, cameras.extrinsics[[1, 3, 0, 2]], atol=1e-9, rtol=0)
        assert given.names == ["a.png", "b.png", "c.png", "d.png"]
        upper = read_given_poses(source, ["A.PNG", "b.png", "C.png", "d.PNG"], [cameras.sizes[0]] * 4)  # any case
        torch.testing.assert_close(upper.extrinsics, given.extrinsics, atol=0, rtol=0)


def test_mismatched_names_are_named_in_the_error(tmp_path):
    cameras = _named(plane_cameras(3), ["a.jpg", "b.jpg", "c.jpg"])
    write_transforms_json(tmp_path / "transforms.json", cameras)
    size = [cameras.sizes[0]]
    with pytest.raises(InputError, match=r"no pose for 1 of 3 photos \(x.png\)"):
        read_given_poses(tmp_path, ["a.png", "b.png", "x.png"], size * 3)
    with pytest.raises(InputError, match=r"1 poses have no photo \(c.jpg\)"):
        read_given_poses(tmp_path, ["a.png", "b.png"], size * 2)
    assert len(read_given_poses(tmp_path, ["a.png", "b.png"], size * 2, allow_extra_poses=True)) == 2
    with pytest.raises(InputError, match="another aspect ratio"):
        read_given_poses(tmp_path, ["a.png", "b.png", "c.png"], [(100, 100)] * 3)
    with pytest.raises(InputError, match="no such file"):
        read_given_poses(tmp_path / "missing.json", ["a.png"], size)


def test_two_different_poses_of_one_photo_are_refused(tmp_path):
    cameras = _named(plane_cameras(3), ["low/a.jpg", "high/a.jpg", "b.jpg"])
    write_transforms_json(tmp_path / "transforms.json", cameras)
    with pytest.raises(InputError, match="differing poses"):
        read_given_poses(tmp_path / "transforms.json", ["a.png", "b.png"], [cameras.sizes[0]] * 2)


def test_a_scene_folder_with_a_binary_model(tmp_path, buu):
    shutil.copytree(buu / "colmap_sparse" / "0", tmp_path / "sparse" / "0")
    text = read_colmap_model(buu / "colmap_text")
    given = read_given_poses(tmp_path, text.names, text.sizes)
    torch.testing.assert_close(given.extrinsics, text.extrinsics, atol=1e-12, rtol=0)


def test_a_scene_folder_gives_its_colmap_model_before_a_transforms_json(tmp_path, buu):
    """`--poses d/` takes d/sparse/0 where d also holds a transforms.json, as it always has."""
    (tmp_path / "sparse").mkdir()
    shutil.copytree(buu / "colmap_text", tmp_path / "sparse" / "0")
    shutil.copy(buu / "transforms_train.json", tmp_path / "transforms.json")  # 22 frames, under other names
    names = [f"{i}.JPG" for i in range(1, 26)]
    cameras = read_given_poses(tmp_path, names, [(500, 375)] * 25)
    assert cameras.names == names
