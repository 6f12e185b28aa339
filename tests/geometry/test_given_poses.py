import logging
import shutil

import pytest
import torch

from lumos3d_cli.data.lom import lom_reference_extrinsics, read_lom_scene
from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.given_poses import FAR_FROM_ORIGIN, centred_if_far, read_given_poses
from lumos3d_cli.io.cameras import Cameras
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


def _moved_by(cameras, shift):
    """The same cameras with the world moved by +shift [3] (their centres included)."""
    rotation = cameras.extrinsics[:, :, :3]
    translation = cameras.extrinsics[:, :, 3] - rotation @ shift
    return Cameras(torch.cat([rotation, translation[:, :, None]], 2), cameras.intrinsics, cameras.sizes, cameras.names)


@pytest.mark.parametrize("shift", [[5e6, -3e6, 2e5], [0.0, 0.0, 6.4e6]])
def test_cameras_far_from_the_origin_are_centred_exactly(shift):
    """Georeferenced poses (UTM, ECEF): the cameras are moved to their mean centre in float64, so a
    point moved with them projects where it did, and the centre says where the frame was."""
    shift = torch.tensor(shift, dtype=torch.float64)
    near = plane_cameras(5)
    far = _moved_by(near, shift)
    centred, origin = centred_if_far(far)
    torch.testing.assert_close(origin, far.centers().mean(0), rtol=1e-15, atol=0)
    torch.testing.assert_close(centred.centers().mean(0), torch.zeros(3, dtype=torch.float64), rtol=0, atol=1e-8)
    points = torch.tensor([[0.3, -0.2, 4.0], [1.0, 0.5, 7.0]], dtype=torch.float64)
    expected, expected_depth = near.project(points)
    pixels, depth = centred.project(points + shift - origin)
    torch.testing.assert_close(pixels, expected, rtol=0, atol=1e-6)
    torch.testing.assert_close(depth, expected_depth, rtol=0, atol=1e-9)
    assert centred.names == far.names and centred.sizes == far.sizes


def test_cameras_near_their_origin_are_left_as_they_are():
    """A dataset's own frame (COLMAP, nerfstudio, LOM: centres within a few spreads of the origin)
    and one camera position a unit or so out are not moved: the outputs stay in the poses' frame."""
    cameras = plane_cameras(5)
    spread = float((cameras.centers() - cameras.centers().mean(0)).square().sum(1).mean().sqrt())
    within = _moved_by(cameras, torch.tensor([0.9 * FAR_FROM_ORIGIN * spread, 0.0, 0.0], dtype=torch.float64))
    # a pan: cameras turned about one centre, whose spread is the rounding of -R^T t (1e-16)
    rotations = cameras.extrinsics[:, :, :3]
    centre = torch.tensor([3.0, 1.0, 0.2], dtype=torch.float64)
    pan = Cameras(torch.cat([rotations, (-rotations @ centre)[:, :, None]], 2), cameras.intrinsics, cameras.sizes,
                  cameras.names)
    for kept in (cameras, within, _moved_by(cameras[[2]], torch.tensor([3.0, 1.0, 0.0], dtype=torch.float64)), pan):
        same, origin = centred_if_far(kept)
        assert origin is None and same is kept
    beyond = _moved_by(cameras, torch.tensor([1.1 * FAR_FROM_ORIGIN * spread, 0.0, 0.0], dtype=torch.float64))
    assert centred_if_far(beyond)[1] is not None
    one_far = _moved_by(cameras[[2]], torch.tensor([0.0, 2e6, 0.0], dtype=torch.float64))
    assert centred_if_far(one_far)[1] is not None  # one centre: measured in units
