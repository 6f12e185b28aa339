import json
import math
import shutil

import numpy as np
import pytest
import torch


from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.given_poses import read_given_poses
from lumos3d_cli.io.camera_files import find_camera_source, read_cameras
from lumos3d_cli.io.cameras import Cameras, make_intrinsics, opengl_to_opencv
from lumos3d_cli.io.colmap import read_colmap_model, read_colmap_points, write_colmap_model
from lumos3d_cli.io.transforms_json import read_transforms_json, write_transforms_json
from lumos3d_cli.rotations import matrix_to_quaternion, quaternion_to_matrix

from factories import random_cameras


def _assert_cameras_close(a: Cameras, b: Cameras, atol=1e-12):
    torch.testing.assert_close(a.extrinsics, b.extrinsics, atol=atol, rtol=0)
    torch.testing.assert_close(a.intrinsics, b.intrinsics, atol=atol, rtol=0)
    assert a.sizes == b.sizes and a.names == b.names


def test_quaternion_matrix_round_trip_including_half_turns():
    quats = torch.randn(1000, 4, dtype=torch.float64)
    quats = quats / quats.norm(dim=1, keepdim=True)
    quats = torch.where(quats[:, :1] < 0, -quats, quats)
    half_turns = torch.tensor([[0.0, 1, 0, 0], [0.0, 0, 1, 0], [0.0, 0, 0, 1], [0.0, 0.6, 0.8, 0]], dtype=torch.float64)
    back = matrix_to_quaternion(quaternion_to_matrix(torch.cat([quats, half_turns])))
    expected = torch.cat([quats, half_turns])
    # q and -q are the same rotation; compare up to sign.
    sign = torch.sign((back * expected).sum(dim=1, keepdim=True))
    torch.testing.assert_close(back * sign, expected, atol=1e-12, rtol=0)
    rotation = quaternion_to_matrix(quats)
    torch.testing.assert_close(rotation @ rotation.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(1000, 3, 3))


def test_transforms_json_round_trip(tmp_path):
    cameras = random_cameras(5)
    write_transforms_json(tmp_path / "transforms.json", cameras)
    _assert_cameras_close(read_transforms_json(tmp_path / "transforms.json"), cameras)
    document = json.loads((tmp_path / "transforms.json").read_text())
    assert "fl_x" not in document and "fl_x" in document["frames"][0]  # per-frame when they differ


def test_shared_intrinsics_go_to_the_top_level(tmp_path):
    cameras = random_cameras(3)
    cameras.intrinsics[:] = cameras.intrinsics[0]
    write_transforms_json(tmp_path / "t.json", cameras)
    document = json.loads((tmp_path / "t.json").read_text())
    assert document["w"] == 320 and document["h"] == 241 and "fl_x" not in document["frames"][0]
    _assert_cameras_close(read_transforms_json(tmp_path / "t.json"), cameras)


def test_colmap_text_round_trip(tmp_path):
    cameras = random_cameras(4, seed=3)
    write_colmap_model(tmp_path, cameras)
    assert (tmp_path / "points3D.txt").is_file()
    _assert_cameras_close(read_colmap_model(tmp_path), cameras, atol=1e-12)


def test_opengl_and_opencv_conventions_agree_on_a_pixel():
    # An OpenGL camera at (1, 2, 3) looking down -z (its identity rotation) sees a world point
    # straight ahead with x to the right and y *up*; project by hand with those axes.
    camera_to_world_gl = torch.eye(4, dtype=torch.float64)
    camera_to_world_gl[:3, 3] = torch.tensor([1.0, 2.0, 3.0])
    point = torch.tensor([[1.5, 2.25, -1.0]], dtype=torch.float64)  # 4 units in front
    fx, fy, cx, cy = 500.0, 400.0, 320.0, 240.0
    x_gl, y_gl, z_gl = (point[0] - camera_to_world_gl[:3, 3]).tolist()
    expected_u = cx + fx * x_gl / -z_gl
    expected_v = cy - fy * y_gl / -z_gl  # image rows grow downwards, GL y grows upwards
    cameras = Cameras.from_camera_to_world(
        opengl_to_opencv(camera_to_world_gl)[None], make_intrinsics(fx, fy, cx, cy), [(640, 480)]
    )
    pixels, depth = cameras.project(point)
    assert pixels[0, 0].tolist() == pytest.approx([expected_u, expected_v], abs=1e-12)
    assert expected_u > cx and expected_v < cy  # right of and above the centre
    assert depth.item() == pytest.approx(4.0)


def test_lom_transforms_agree_with_its_colmap_model(buu):
    """LOM ships the same cameras twice: transforms.json (OpenGL, rescaled world) and COLMAP
    text (OpenCV). Relative rotations must match exactly; relative translations up to one scale."""
    nerf = read_transforms_json(buu / "transforms_train.json")
    colmap = read_colmap_model(buu / "colmap_text")
    by_name = {name.lower(): i for i, name in enumerate(colmap.names)}
    colmap = colmap[[by_name[name.split("/")[-1].lower()] for name in nerf.names]]
    a, b = nerf.relative_to(0), colmap.relative_to(0)
    torch.testing.assert_close(a.extrinsics[:, :, :3], b.extrinsics[:, :, :3], atol=1e-9, rtol=0)
    ratio = a.extrinsics[1:, :, 3].norm(dim=1) / b.extrinsics[1:, :, 3].norm(dim=1)
    assert ratio.std() / ratio.mean() < 1e-6
    torch.testing.assert_close(a.extrinsics[1:, :, 3] / ratio.mean(), b.extrinsics[1:, :, 3], atol=1e-6, rtol=0)
    torch.testing.assert_close(nerf.intrinsics, colmap.intrinsics)
    assert nerf.sizes[0] == (500, 375)


def test_every_camera_source_restore_reads_is_read_by_read_cameras(buu):
    """A binary COLMAP model (or one of its files) and a LOM folder of transforms splits, as
    `restore --poses` takes them; the splits' frames together, in file-name order."""
    text = read_colmap_model(buu / "colmap_text")
    for source in (buu / "colmap_sparse" / "0", buu / "colmap_sparse" / "0" / "images.bin"):
        assert find_camera_source(source) == buu / "colmap_sparse" / "0"
        binary = read_cameras(source)
        assert sorted(binary.names) == sorted(text.names)
        order = [binary.names.index(name) for name in text.names]
        torch.testing.assert_close(binary[order].extrinsics, text.extrinsics)
    lom = read_cameras(buu)
    splits = [read_transforms_json(buu / f"transforms_{split}.json") for split in ("test", "train", "val")]
    names = [name for split in splits for name in split.names]
    assert len(names) == 26 and names.count("high/1.JPG") == 2  # LOM lists frame 1 in test and in val
    assert lom.names == names[:-1] and len(set(lom.names)) == 25  # ...read once
    torch.testing.assert_close(lom.extrinsics, torch.cat([split.extrinsics for split in splits])[:-1])


def test_a_folder_names_its_cameras_in_one_order_and_stray_transforms_files_are_no_cameras(buu, tmp_path):
    scene = tmp_path / "scene"
    (scene / "sparse").mkdir(parents=True)
    shutil.copytree(buu / "colmap_text", scene / "sparse" / "0")
    shutil.copy(buu / "transforms_train.json", scene / "transforms.json")
    # one order for restore --poses, render --poses, info and view: the COLMAP model first (restore's
    # read sparse/0 where render read transforms.json, which colmap2nerf re-centres and rescales)
    assert find_camera_source(scene) == scene / "sparse" / "0"
    names = read_cameras(scene / "sparse" / "0").names
    given = read_given_poses(scene, names, [(500, 375)] * len(names), allow_extra_poses=True)
    assert torch.equal(given.extrinsics, read_cameras(scene).extrinsics)
    shutil.rmtree(scene / "sparse")
    assert find_camera_source(scene) == scene / "transforms.json"
    (tmp_path / "graded").mkdir()
    (tmp_path / "graded" / "transforms_grading.json").write_text('{"note": "a colour grade, no cameras"}')
    assert find_camera_source(tmp_path / "graded") is None


def test_scene_sparse_model_reprojects_its_points(shared_data):
    """Our reading of a COLMAP model must put each 3D point onto the 2D observation it came from."""
    folder = shared_data / "scenes" / "kitchen" / "sparse" / "0"
    cameras = read_cameras(shared_data / "scenes" / "kitchen")
    assert len(cameras) == 17 and cameras.sizes[0] == (512, 342)
    points = read_colmap_points(folder / "points3D.txt")
    lines = [l for l in (folder / "images.txt").read_text().splitlines() if not l.startswith("#")]
    header = lines[0].split()
    observations = np.asarray(lines[1].split(), dtype=np.float64).reshape(-1, 3)
    observed = observations[observations[:, 2] >= 0]
    index = cameras.names.index(header[9])
    lookup = {pid: i for i, pid in enumerate(points.ids)}
    xyz = torch.from_numpy(points.xyz[[lookup[int(pid)] for pid in observed[:, 2]]])
    pixels, depth = cameras[index].project(xyz)
    assert (depth > 0).all()
    error = (pixels[0].numpy() - observed[:, :2])
    assert np.median(np.linalg.norm(error, axis=1)) < 2.0


def test_rescale_and_relative_frame():
    cameras = random_cameras(3)
    half = cameras.rescaled(160, 120)
    assert half.sizes == [(160, 120)] * 3
    assert half.intrinsics[0, 0, 0] == pytest.approx(cameras.intrinsics[0, 0, 0].item() * 0.5)
    assert half.intrinsics[0, 1, 2] == pytest.approx(cameras.intrinsics[0, 1, 2].item() * 120 / 241)
    relative = cameras.relative_to(0)
    torch.testing.assert_close(relative.extrinsics[0], torch.eye(4, dtype=torch.float64)[:3])
    point = torch.randn(1, 3, dtype=torch.float64)
    original_pixels, _ = cameras.project(point)
    point_in_first = (cameras.extrinsics[0, :, :3] @ point[0] + cameras.extrinsics[0, :, 3])[None]
    relative_pixels, _ = relative.project(point_in_first)
    torch.testing.assert_close(relative_pixels, original_pixels)


def test_rescaled_to_per_view_sizes_maps_pixels_by_each_views_stretch():
    """A photo stretched from w x h to W x H moves every pixel (u, v) to (u W/w, v H/h) (pixel
    corners at integers): the rescaled camera must project a point exactly there."""
    cameras = random_cameras(3)  # 320 x 241
    sizes = [(500, 375), (160, 241), (320, 100)]
    stretched = cameras.rescaled_to(sizes)
    assert stretched.sizes == sizes and stretched.names == cameras.names
    torch.testing.assert_close(stretched.extrinsics, cameras.extrinsics)
    points = torch.randn(5, 3, dtype=torch.float64) + torch.tensor([0.0, 0.0, 4.0], dtype=torch.float64)
    before, depth_before = cameras.project(points)
    after, depth_after = stretched.project(points)
    factors = torch.tensor([[w / 320, h / 241] for w, h in sizes], dtype=torch.float64)
    torch.testing.assert_close(after, before * factors[:, None, :], atol=1e-9, rtol=0)
    torch.testing.assert_close(depth_after, depth_before)
    torch.testing.assert_close(stretched.rescaled_to(cameras.sizes).intrinsics, cameras.intrinsics, atol=1e-12, rtol=0)
    with pytest.raises(ValueError, match="2 image sizes for 3 cameras"):
        cameras.rescaled_to(sizes[:2])


def test_camera_angle_only_and_missing_size(tmp_path):
    import cv2

    cv2.imwrite(str(tmp_path / "r_0.png"), np.zeros((60, 80, 3), np.uint8))
    document = {"camera_angle_x": 2 * math.atan(0.5), "frames": [{"file_path": "./r_0", "transform_matrix": np.eye(4).tolist()}]}
    (tmp_path / "transforms.json").write_text(json.dumps(document))
    cameras = read_transforms_json(tmp_path / "transforms.json")
    assert cameras.sizes == [(80, 60)]
    assert cameras.intrinsics[0, 0, 0].item() == pytest.approx(80.0)
    assert cameras.intrinsics[0, 0, 2].item() == 40.0


def test_bad_camera_files(tmp_path):
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(InputError, match=r"bad\.json: invalid JSON"):
        read_cameras(tmp_path / "bad.json")
    (tmp_path / "empty.json").write_text("{}")
    with pytest.raises(InputError, match="no 'frames' list"):
        read_cameras(tmp_path / "empty.json")
    (tmp_path / "f.json").write_text(json.dumps({"frames": [{"transform_matrix": np.eye(4).tolist(), "w": 4, "h": 4}]}))
    with pytest.raises(InputError, match="no focal length"):
        read_cameras(tmp_path / "f.json")
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(InputError, match="no cameras found"):
        read_cameras(tmp_path / "empty_dir")
    assert find_camera_source(tmp_path / "missing") is None


def test_concatenate_keeps_order_sizes_and_names():
    first = Cameras(torch.eye(3, 4)[None].double(), torch.eye(3)[None].double() * 2, [(4, 3)], ["a.png"])
    second = Cameras(torch.eye(3, 4).repeat(2, 1, 1), torch.eye(3).repeat(2, 1, 1), [(8, 6), (2, 1)], ["b.png", "c.png"])
    joined = Cameras.concatenate([first, second])
    assert joined.names == ["a.png", "b.png", "c.png"] and joined.sizes == [(4, 3), (8, 6), (2, 1)]
    assert joined.extrinsics.dtype == torch.float64 and joined.intrinsics[0, 0, 0] == 2 and joined.intrinsics[1, 0, 0] == 1
    with pytest.raises(ValueError):
        Cameras.concatenate([])


def test_a_camera_holding_nan_is_named_by_its_view():
    """A transforms.json pose with NaN was "extrinsics: 6 of 48 values are NaN or Inf": which view?"""
    intrinsics = make_intrinsics(50.0, 50.0, 32.0, 24.0).expand(4, 3, 3).clone()
    extrinsics = torch.eye(4)[:3].expand(4, 3, 4).clone()
    extrinsics[2, 0, 3] = float("nan")
    cameras = Cameras(extrinsics, intrinsics, [(64, 48)] * 4, ["a.jpg", "b.jpg", "c.jpg", "d.jpg"])
    with pytest.raises(InputError, match=r"poses.json: the pose of view 2 \(c.jpg\) holds NaN or Inf; correct the file"):
        cameras.require_valid("poses.json")
    intrinsics[0, 0, 0] = float("inf")
    with pytest.raises(InputError, match=r"the intrinsics of view 0 \(a.jpg\) holds NaN"):
        Cameras(torch.eye(4)[:3].expand(4, 3, 4).clone(), intrinsics, [(64, 48)] * 4, ["a.jpg", "b.jpg", "c.jpg", "d.jpg"]).require_valid("poses.json")


def test_distorted_colmap_cameras_are_warned_of_in_one_line(tmp_path, caplog):
    from synthetic_scene import plane_cameras

    cameras = plane_cameras(3)
    write_colmap_model(tmp_path, cameras)
    lines = (tmp_path / "cameras.txt").read_text().splitlines()
    distorted = []
    for line in lines:
        words = line.split()
        if words and not line.startswith("#"):  # CAMERA_ID PINHOLE W H fx fy cx cy -> OPENCV with 4 zero coefficients
            words[1] = "OPENCV"
            line = " ".join(words + ["0.01", "0", "0", "0"])
        distorted.append(line)
    (tmp_path / "cameras.txt").write_text("\n".join(distorted) + "\n")
    for binary in tmp_path.glob("*.bin"):  # the text form edited alone: the binary one would be read first
        binary.unlink()
    read_colmap_model(tmp_path)
    warnings = [record.getMessage() for record in caplog.records if "distortion" in record.getMessage()]
    assert len(warnings) == 1 and "camera(s) 1 (OPENCV), 2 (OPENCV), 3 (OPENCV) are ignored" in warnings[0]


def test_colmap_models_read_as_colmap_reads_them(tmp_path):
    """The binary form first (a bundle adjuster writing .bin into the folder left a stale .txt read);
    names without trailing blanks; an images.txt without its POINTS2D lines refused (it lost every
    second image); fisheye models refused (an equidistant projection is no pinhole, zero
    coefficients or not); text that is not UTF-8 named."""
    from synthetic_scene import plane_cameras

    cameras = plane_cameras(4)
    write_colmap_model(tmp_path / "model", cameras)
    model = tmp_path / "model"
    stale = (model / "cameras.txt").read_text().replace(" PINHOLE ", " PINHOLE ").splitlines()
    stale = [line if line.startswith("#") else " ".join(line.split()[:4] + [str(float(v) * 2) for v in line.split()[4:]])
             for line in stale]
    (model / "cameras.txt").write_text("\n".join(stale) + "\n")  # the text form now disagrees with the binary one
    torch.testing.assert_close(read_colmap_model(model).intrinsics, cameras.intrinsics.double())

    text = tmp_path / "text"
    text.mkdir()
    shutil.copy(model / "cameras.txt", text)
    lines = (model / "images.txt").read_text().splitlines()
    image_lines = [line for line in lines if not line.startswith("#")][0::2]
    header = [line for line in lines if line.startswith("#")]
    (text / "images.txt").write_text("\n".join(header + [image_lines[0] + "   "]) + "\n\n" + "\n".join(image_lines[1:]) + "\n")
    with pytest.raises(InputError, match=r"images.txt: image '.*' is followed by another image line, not its POINTS2D"):
        read_colmap_model(text)
    # an image's two lines deleted by hand (the header's count now stale) still reads
    (text / "images.txt").write_text("\n".join(header + [image_lines[0], "", image_lines[2], ""]) + "\n")
    assert len(read_colmap_model(text)) == 2
    (text / "images.txt").write_text("\n".join(image_lines[0:1]) + "   \n\n")
    assert read_colmap_model(text).names == [cameras.names[0]]  # trailing blanks are no part of the name

    for model_name, params in (("OPENCV_FISHEYE", "100 100 32 24 0 0 0 0"), ("FOV", "100 100 32 24 0"),
                               ("SIMPLE_RADIAL_FISHEYE", "100 32 24 0")):
        (text / "cameras.txt").write_text(f"1 {model_name} 64 48 {params}\n")
        with pytest.raises(InputError, match=f"camera model {model_name} is no perspective .pinhole. camera; undistort"):
            read_colmap_model(text)
    (text / "cameras.txt").write_bytes("1 PINHOLE 64 48 100 100 32 24\n".encode())
    (text / "images.txt").write_bytes(b"1 1 0 0 0 0 0 0 1 caf\xe9.jpg\n\n")  # Latin-1, not UTF-8
    with pytest.raises(InputError, match="images.txt: not UTF-8 text"):
        read_colmap_model(text)


def test_transforms_json_values_of_the_wrong_kind_are_named(tmp_path):
    document = {"w": 64, "h": 48, "fl_x": 50, "frames": [{"file_path": "a.png", "transform_matrix": torch.eye(4).tolist()}]}
    path = tmp_path / "transforms.json"
    for change, message in (({"cx": None}, "has cx None, which is not a number"), ({"k1": "abc"}, "has k1 'abc'"),
                            ({"frames": [[1, 2]]}, "frame 0 is list"), ({"frames": {"a": 1}}, "no 'frames' list"),
                            ({"frames": []}, "its 'frames' list is empty; the file holds no camera"),
                            ({"camera_model": "OPENCV_FISHEYE"}, "camera_model 'OPENCV_FISHEYE' is not a perspective"),
                            ({"camera_model": "EQUIRECTANGULAR"}, "is not a perspective camera"),
                            ({"w": True}, "has w True, which is not a number"),  # was a frame 1 pixel wide
                            ({"frames": [{"file_path": "a.png", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0],
                                                                                      [0, 0, 1, 0], [0, 0, 0, 0]]}]},
                             r"last row \[0.0, 0.0, 0.0, 0.0\], but a camera pose's is \[0, 0, 0, 1\]")):
        path.write_text(json.dumps({**document, **change}))
        with pytest.raises(InputError, match=message):
            read_transforms_json(path)
    # a frame's own field of view wins over the top level's focal length, as the docstring says
    frame = {"file_path": "a.png", "transform_matrix": torch.eye(4).tolist(), "camera_angle_x": 2 * math.atan(0.5)}
    path.write_text(json.dumps({**document, "frames": [frame]}))
    assert read_transforms_json(path).intrinsics[0, 0, 0].item() == pytest.approx(64.0)
    # without w/h, the image is found by its stem in any case and with any suffix
    cv2 = pytest.importorskip("cv2")
    cv2.imwrite(str(tmp_path / "A.TIF"), np.zeros((30, 40, 3), np.uint8))
    path.write_text(json.dumps({"fl_x": 50, "frames": [{"file_path": "a", "transform_matrix": torch.eye(4).tolist()}]}))
    assert read_transforms_json(path).sizes == [(40, 30)]
