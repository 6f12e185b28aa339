"""Bad input exits 2 with one line naming it, before the work where it can be known before (issue
38, rows 9-12); --debug adds the traceback and keeps the exit code."""

import errno
import json
import shutil

import cv2
import numpy as np
import pycolmap
import pytest
import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.colmap import read_colmap_model, write_colmap_model
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.io.image_write import write_image
from lumos3d_cli.io.ply import write_ply
from lumos3d_cli.pipeline import restore_outputs

from assertions import expect_input_error
from output_files import copy_photos, restore_args, snapshot
from processes import run_lumos3d

SIX = ["1.JPG", "2.JPG", "3.JPG", "4.JPG", "5.JPG", "6.JPG"]



def _transforms(path, names, change):
    frames = [{"file_path": name, "transform_matrix": [[1, 0, 0, 0.1 * i], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}
              for i, name in enumerate(names)]
    document = {"fl_x": 400.0, "fl_y": 400.0, "cx": 250.0, "cy": 187.5, "w": 500, "h": 375, "frames": frames}
    change(document)
    path.write_text(json.dumps(document))
    return path


_POSE_FAULTS = {
    "singular": (lambda d: d["frames"][2].update(transform_matrix=[[1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
                 "the pose of view 2 (3.JPG) holds a matrix that is not a rotation"),
    "scaled": (lambda d: d["frames"][0].update(transform_matrix=[[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]]),
               "the pose of view 0 (1.JPG) holds a matrix that is not a rotation"),
    "zero-focal": (lambda d: d.update(fl_x=0.0), "the focal length of view 0 (1.JPG) is not positive"),
    # NeRF's field of view instead of a focal length: 0 divided by zero, pi gave a focal of 1e-14
    "zero-angle": (lambda d: [d.pop(k) for k in ("fl_x", "fl_y")] and d.update(camera_angle_x=0.0),
                   "frame 0 has camera_angle_x 0.0, but a field of view lies between 0 and pi radians"),
    "straight-angle": (lambda d: [d.pop(k) for k in ("fl_x", "fl_y")] and d.update(camera_angle_x=3.141592653589793),
                       "frame 0 has camera_angle_x 3.141592653589793, but a field of view lies between 0 and pi"),
    "text-focal": (lambda d: d.update(fl_x="wide"), "frame 0 has fl_x 'wide', which is not a number"),
    "text-width": (lambda d: d.update(w="abc"), "frame 0 has w 'abc', which is not a number"),
    "nan-width": (lambda d: d.update(w=float("nan")), "frame 0 has the image size nanx375"),
    "zero-width": (lambda d: d.update(w=0), "the image size of view 0 (1.JPG) is 0x375 pixels; correct the file"),
}


@pytest.mark.parametrize("fault", list(_POSE_FAULTS))
def test_row9_poses_that_are_not_cameras_are_refused_before_the_work(tmp_path, buu, garbage_checkpoint, fault, run_cli):
    change, message = _POSE_FAULTS[fault]
    photos = copy_photos(buu, tmp_path / "photos")
    poses = _transforms(tmp_path / "poses.json", SIX, change)
    expect_input_error(run_cli(*restore_args(photos, tmp_path / "out" / "scene.ply", garbage_checkpoint, "--poses", poses)),
                       f"{poses}: {message}")
    assert not (tmp_path / "out").exists()


def test_row9_a_colmap_image_with_a_zero_quaternion_is_named(tmp_path, buu, garbage_checkpoint, run_cli):
    photos = copy_photos(buu, tmp_path / "photos", SIX[:2])
    model = tmp_path / "sparse"
    extrinsics = torch.eye(3, 4, dtype=torch.float64)[None].repeat(2, 1, 1)
    extrinsics[1, 0, 3] = 1.0
    intrinsics = torch.tensor([[400.0, 0, 250], [0, 400, 187.5], [0, 0, 1]], dtype=torch.float64)[None].repeat(2, 1, 1)
    write_colmap_model(model, Cameras(extrinsics, intrinsics, [(500, 375)] * 2, SIX[:2]))
    for binary in model.glob("*.bin"):
        binary.unlink()
    images = model / "images.txt"
    images.write_text(images.read_text().replace("2 1.0 0.0 0.0 0.0", "2 0 0 0 0", 1).replace(
        "2 1 0 0 0", "2 0 0 0 0", 1))
    assert "2 0 0 0 0" in images.read_text()
    expect_input_error(run_cli(*restore_args(photos, tmp_path / "out" / "scene.ply", garbage_checkpoint,
                                                 "--poses", model)),
                       f"{model}: image 2.JPG has the rotation quaternion [0.0, 0.0, 0.0, 0.0]", "not a pose")


def test_row9_an_output_through_a_dangling_link_is_refused_before_the_work(tmp_path, buu, garbage_checkpoint, run_cli):
    photos = copy_photos(buu, tmp_path / "photos")
    (tmp_path / "link").symlink_to(tmp_path / "nowhere")
    expect_input_error(run_cli(*restore_args(photos, tmp_path / "link" / "scene.ply", garbage_checkpoint)),
                       f"{tmp_path / 'link'} is a link to {tmp_path / 'nowhere'}, which does not exist")


def test_row9_a_full_disk_names_the_output_and_changes_nothing(tmp_path, buu, run_cli, random_checkpoint, earlier_restore, monkeypatch):
    out = shutil.copytree(earlier_restore, tmp_path / "out")
    before = snapshot(out)

    def full_disk(path, gaussians):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(restore_outputs, "write_ply", full_disk)
    result = run_cli(*restore_args(copy_photos(buu, tmp_path / "photos", SIX[:3]), out / "scene.ply", random_checkpoint))
    expect_input_error(result, f"{out}: no space left on the device while writing the outputs (nothing was changed)")
    assert snapshot(out) == before


def test_row9_render_info_and_train_refuse_what_they_cannot_use(tmp_path, tiny_config, run_cli):
    empty = tmp_path / "empty.ply"
    write_ply(empty, Gaussians(torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 1, 3)))
    expect_input_error(run_cli("render", empty, "--orbit", 3, "-o", tmp_path / "frames"),
                       f"{empty}: holds no Gaussians; there is nothing to render")
    expect_input_error(run_cli("info", "/dev/null"), "/dev/null: is neither a file nor a folder")
    ascii_empty = tmp_path / "ascii.ply"
    ascii_empty.write_text("ply\nformat ascii 1.0\nelement vertex 0\n" + "".join(
        f"property float {name}\n" for name in ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
                                                "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")) + "end_header\n")
    result = run_cli("render", ascii_empty, "--orbit", 3, "-o", tmp_path / "frames")
    expect_input_error(result, f"{ascii_empty}: holds no Gaussians; there is nothing to render")
    assert len(result.err.strip().splitlines()) == 1
    # an empty scene's statistics are null, not NaN: the JSON stays JSON
    info = run_cli("info", empty, "--json")
    assert info.code == 0 and json.loads(info.out)["opacity"] == {"min": None, "median": None, "mean": None, "max": None}
    for value in ("-1e-4", ".nan", ".inf"):
        expect_input_error(run_cli("train", tiny_config(name="lr"), f"optim.lr={value}"), "lr: ", "must be a number of at least 0")
    assert not (tmp_path / "frames").exists() and not (tmp_path / "lr").exists()


def test_row9_debug_keeps_exit_2_and_adds_the_traceback(tmp_path):
    result = run_lumos3d("--debug", "info", tmp_path / "missing.ply")
    assert result.code == 2 and "Traceback" in result.err
    assert result.err.strip().splitlines()[-1] == f"error: {tmp_path / 'missing.ply'}: no such file or folder"


def test_row10_a_photo_too_small_for_one_network_patch_is_refused_by_name(tmp_path, buu, random_checkpoint, run_cli):
    photos = copy_photos(buu, tmp_path / "photos", SIX[:2])
    write_image(photos / "tiny.png", np.full((1, 1, 3), 0.5, np.float32))
    expect_input_error(run_cli(*restore_args(photos, tmp_path / "out" / "scene.ply", random_checkpoint)),
                       f"{photos / 'tiny.png'}: is 1x1 pixels, too small for the network (at least 14 pixels a side)")
    assert not (tmp_path / "out").exists()


def test_row11_references_that_do_not_match_are_refused_before_the_work(tmp_path, buu, garbage_checkpoint, run_cli):
    photos = copy_photos(buu, tmp_path / "photos", SIX[:3])
    references = tmp_path / "references"
    references.mkdir()
    for name in SIX[:2]:
        shutil.copy(buu / "high" / name, references / name)
    expect_input_error(run_cli(*restore_args(photos, tmp_path / "out" / "scene.ply", garbage_checkpoint,
                                                 "--reference", references)),
                       f"--reference {references}: no image named 3.* for input 3.JPG")


def test_row11_lpips_weights_without_references_are_refused_not_ignored(tmp_path, buu, random_checkpoint, run_cli):
    photos = copy_photos(buu, tmp_path / "photos", SIX[:2])
    weights = tmp_path / "lpips.pth"
    weights.write_bytes(b"")
    expect_input_error(run_cli(*restore_args(photos, tmp_path / "out" / "scene.ply", random_checkpoint,
                                             "--lpips-weights", weights)),
                       f"--lpips-weights {weights}: LPIPS is scored against reference images")
    assert not (tmp_path / "out").exists()


def test_row12_black_and_white_photos_are_named_once(tmp_path, buu, random_checkpoint):
    photos = copy_photos(buu, tmp_path / "photos", SIX[:3])
    write_image(photos / "black.png", np.zeros((375, 500, 3), np.float32))
    write_image(photos / "white.png", np.ones((375, 500, 3), np.float32))
    result = run_lumos3d(*restore_args(photos, tmp_path / "out" / "scene.ply", random_checkpoint))
    assert result.code == 0, result.err
    assert result.err.count("entirely black") == 1 and "black.png is entirely black" in result.err
    assert result.err.count("entirely saturated") == 1 and "white.png is entirely saturated" in result.err
    assert "did you mean" not in result.err  # buu's dark photos suit the low-light mode


def test_row12_empty_photos_are_judged_at_their_own_size_and_a_set_of_them_refused(tmp_path, buu, random_checkpoint, run_cli):
    """A black photo of another size than the others (stretched, it gained grey levels and passed
    for an image: fused, it laid black wedges over two views) and a lens cap's frame of codes 0 to 2
    are named and not fused; photos that are all empty are refused (a made-up scene, exit 0)."""
    photos = copy_photos(buu, tmp_path / "photos", SIX[:3])
    rng = np.random.default_rng(0)
    write_image(photos / "black.png", rng.integers(0, 2, (300, 400, 3)).astype(np.float32) / 255)  # another size
    write_image(photos / "cap.png", rng.integers(0, 3, (375, 500, 3)).astype(np.float32) / 255)
    result = run_lumos3d(*restore_args(photos, tmp_path / "out" / "scene.ply", random_checkpoint, "--json"))
    assert result.code == 0, result.err
    assert "black.png, cap.png are entirely black" in result.err
    restored = cv2.imread(str(tmp_path / "out" / "restored" / "black.png"))
    assert restored.shape == (300, 400, 3) and restored.max() <= 1  # its view is the photo itself
    empty = tmp_path / "empty"
    empty.mkdir()
    write_image(empty / "a.png", np.zeros((120, 160, 3), np.float32))
    write_image(empty / "b.png", np.ones((120, 160, 3), np.float32))
    expect_input_error(run_cli(*restore_args(empty, tmp_path / "none" / "scene.ply", random_checkpoint)),
                       "every photo is entirely black or saturated; there is nothing to restore")
    assert not (tmp_path / "none").exists()
    # one such photo alone: a scene of 21,000 Gaussians made up from a blank frame, exit 0
    expect_input_error(run_cli(*restore_args(empty / "a.png", tmp_path / "none" / "scene.ply", random_checkpoint)),
                       "a.png: the photo is entirely black or saturated; there is nothing to restore")
    assert not (tmp_path / "none").exists()


def test_row12_a_photo_too_large_to_render_is_refused_before_the_work(tmp_path, buu, random_checkpoint, run_cli):
    """Its view renders at its own size: beyond 16384 pixels a side the render refused it after the
    network, structure-from-motion and refinement, naming no photo."""
    photos = copy_photos(buu, tmp_path / "photos", SIX[:2])
    write_image(photos / "panorama.png", np.full((20, 16400, 3), 0.1, np.float32))
    result = run_cli(*restore_args(photos, tmp_path / "out" / "scene.ply", random_checkpoint))
    expect_input_error(result, "panorama.png: is 16400x20 pixels; lumos3d renders views of at most 16384 pixels a side")
    assert not (tmp_path / "out").exists()


def test_row12_a_photo_copied_under_another_name_is_named(tmp_path, buu, random_checkpoint):
    photos = copy_photos(buu, tmp_path / "photos", SIX[:3])
    shutil.copy(photos / SIX[1], photos / "copy.JPG")
    result = run_lumos3d(*restore_args(photos, tmp_path / "out" / "scene.ply", random_checkpoint))
    assert result.code == 0, result.err
    assert result.err.count("holds the same image as") == 1
    assert f"{SIX[1]} holds the same image as copy.JPG" in result.err or f"copy.JPG holds the same image as {SIX[1]}" in result.err


def test_row12_dark_photos_in_the_over_exposure_mode_are_questioned(tmp_path, buu, random_checkpoint):
    photos = copy_photos(buu, tmp_path / "photos", SIX[:2])
    result = run_lumos3d(*restore_args(photos, tmp_path / "out" / "scene.ply", random_checkpoint, "--mode", "over-exposure"))
    assert result.code == 0, result.err
    assert "the photos are dark (mean level 0.08) for the over-exposure mode" in result.err
    assert "did you mean the low-light mode?" in result.err


def test_row12_bright_photos_among_dark_ones_are_named(tmp_path, buu, random_checkpoint):
    """The mode was checked against the set's mean: two dark and two over-exposed photos average
    0.5, between both limits, and the low-light restoration blew the bright ones to white unwarned."""
    photos = copy_photos(buu, tmp_path / "photos", SIX[:2])
    for name in ("5.jpg", "6.jpg"):
        shutil.copy(buu / "over_exp" / name, photos / f"bright-{name}")
    result = run_lumos3d(*restore_args(photos, tmp_path / "out" / "scene.ply", random_checkpoint, "--refine-steps", 0))
    assert result.code == 0, result.err
    said = " ".join(result.err.split())
    assert "2 of 4 photos are bright for the low-light mode, which brightens: bright-5.jpg (0.9" in said, said
    assert "restore them apart, the bright photos in the over-exposure mode" in said


def test_row12_a_white_photo_stays_white_in_the_over_exposure_model(tmp_path, run_cli):
    """The bundled over-exposure operator darkens what it sees; an all-saturated photo records
    nothing to darken, so its restoration is the photo itself. Alone, it is refused: nothing to
    restore (it wrote a scene made up from the blank frame)."""
    photos = tmp_path / "photos"
    photos.mkdir()
    write_image(photos / "white.png", np.ones((120, 160, 3), np.float32))
    output = tmp_path / "out" / "scene.ply"
    expect_input_error(run_cli("restore", photos, "-o", output, "--mode", "over-exposure", "--preset", "fast"),
                       "white.png: the photo is entirely black or saturated; there is nothing to restore")
    rng = np.random.default_rng(0)
    for name in ("a.png", "b.png"):  # bright photos that recorded something
        write_image(photos / name, (0.7 + 0.3 * rng.random((120, 160, 3))).astype(np.float32))
    result = run_cli("restore", photos, "-o", output, "--mode", "over-exposure", "--preset", "fast")
    assert result.code == 0, result.err
    restored = cv2.imread(str(output.parent / "restored" / "white.png"))
    assert restored.min() == 255


def test_row12_photo_names_with_spaces_stay_whole_for_pycolmap(tmp_path):
    extrinsics = torch.eye(3, 4, dtype=torch.float64)[None].repeat(2, 1, 1)
    extrinsics[1, 0, 3] = 1.0
    intrinsics = torch.tensor([[100.0, 0, 50], [0, 100, 40], [0, 0, 1]], dtype=torch.float64)[None].repeat(2, 1, 1)
    names = ["my photo 1.jpg", "my  photo  2.jpg"]  # two spaces in a row, too
    write_colmap_model(tmp_path, Cameras(extrinsics, intrinsics, [(100, 80)] * 2, names))
    assert sorted(image.name for image in pycolmap.Reconstruction(str(tmp_path)).images.values()) == sorted(names)
    assert sorted(read_colmap_model(tmp_path).names) == sorted(names)  # the text model, as lumos3d reads it back
    for binary in tmp_path.glob("*.bin"):
        binary.unlink()
    assert sorted(read_colmap_model(tmp_path).names) == sorted(names)


def test_row12_a_garbage_torch_file_is_one_line(tmp_path, run_cli):
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(bytes(range(256)) * 4)
    result = run_cli("info", garbage)
    expect_input_error(result, f"{garbage}: damaged, or holds objects other than tensors")
    assert len(result.err.strip().splitlines()) == 1
    # a byte or a word: the unpickler fails with IndexError or KeyError, not UnpicklingError
    for content in (b"R", b"hello", b"q"):
        short = tmp_path / f"short-{content.decode()}.pt"
        short.write_bytes(content)
        result = run_cli("info", short)
        expect_input_error(result, f"{short}: cannot read as a torch checkpoint")
        assert len(result.err.strip().splitlines()) == 1


def test_row12_an_eval_scene_without_transforms_test_json_names_the_file(tmp_path, buu, run_cli):
    scene = tmp_path / "lom" / "sc"
    for folder in ("high", "low"):
        shutil.copytree(buu / folder, scene / folder)
    expect_input_error(run_cli("eval", tmp_path / "lom", "--scenes", "sc", "--out", tmp_path / "report"),
                       f"{scene}: not a LOM-layout scene: {scene / 'transforms_test.json'} is missing")
    expect_input_error(run_cli("eval", scene, "--out", tmp_path / "report"), f"{scene / 'transforms_test.json'} is missing")
    assert not (tmp_path / "report").exists()
