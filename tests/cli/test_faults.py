"""Faults and bad input through the real command in a child process (issue 17): runs stopped by a
signal leave nothing half-written and say so in one line; a killed run's leftovers are removed by
the next; a re-run replaces the output set; bad inputs are refused before any work, naming the
file or value; photos of different sizes are restored each at its own size, without stretching."""

import json
import shutil
import signal
import struct

import cv2
import numpy as np
import OpenImageIO as oiio
import pytest
from safetensors import safe_open
from safetensors.torch import save_file
from skimage.metrics import peak_signal_noise_ratio

from lumos3d_cli.io.ply import write_ply
from lumos3d_cli.model.checkpoints import save_checkpoint
from lumos3d_cli.model.lumos3d import build_model
from lumos3d_cli.viewer.scene_folder import load_viewer_scene

from assertions import expect_input_error
from output_files import listing
from factories import random_gaussians
from processes import cli_started, hidden_entries, interrupt_when, run_lumos3d, signal_name

SIGNALS = [signal.SIGINT, signal.SIGTERM, signal.SIGHUP]


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "scene.ply"
    write_ply(path, random_gaussians(2000, 0))
    return path


def _photos(buu, folder, names):
    folder.mkdir()
    for name in names:
        shutil.copy(buu / "low" / name, folder / name)
    return folder


@pytest.fixture(scope="module")
def photos(tmp_path_factory, buu):
    return _photos(buu, tmp_path_factory.mktemp("photos") / "dark", ["1.JPG", "2.JPG", "3.JPG", "4.JPG", "5.JPG", "6.JPG"])


def _restore(photos, output, weights, *extra):
    """A quick restore: network cameras, no refinement (the tests are about files and signals)."""
    return ("restore", photos, "-o", output, "--checkpoint", weights, "--geometry", "network", "--preset", "fast",
            "--refine-steps", 0, *extra)


@pytest.fixture(scope="module")
def first_restore(tmp_path_factory, photos, random_checkpoint):
    """The outputs of one restore of six photos (copied by the tests that change them)."""
    out = tmp_path_factory.mktemp("first") / "out"
    result = run_lumos3d(*_restore(photos, out / "scene.ply", random_checkpoint))
    assert result.code == 0, result.err
    return out


def _contents(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _has_staging(folder):
    return folder.is_dir() and any(p.name.startswith(".staging.") for p in folder.iterdir())


def _expect_interrupted(result, signum):
    assert result.code == 128 + signum, (result.code, result.err[-3000:])
    assert result.last_line.startswith(f"interrupted by {signal_name(signum)}"), result.err[-3000:]
    assert "Traceback" not in result.err


# -- row 1, 14: signals -----------------------------------------------------------------------------


def _render_args(tmp_path, frames_count=5000):
    """A render that runs for seconds (5000 frames of 128 px) until a test stops it."""
    return ("render", tmp_path / "scene.ply", "--orbit", frames_count, "-o", tmp_path / "frames", "--width", 128,
            "--video", tmp_path / "orbit.mp4")


def _render_is_writing(tmp_path):
    frames = tmp_path / "frames"
    return (_has_staging(frames) and any(frames.glob(".staging.*/00002.png"))
            and any(tmp_path.glob(".orbit.*.tmp.mp4")))


@pytest.mark.parametrize("signum", SIGNALS, ids=signal_name)
def test_render_stopped_by_a_signal_removes_its_temporary_outputs(tmp_path, scene_file, signum):
    shutil.copy(scene_file, tmp_path / "scene.ply")
    result = interrupt_when(_render_args(tmp_path), lambda _: _render_is_writing(tmp_path), signum)
    _expect_interrupted(result, signum)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.ply"]


def test_leftovers_of_a_killed_render_are_removed_by_the_next_run(tmp_path, scene_file):
    shutil.copy(scene_file, tmp_path / "scene.ply")
    killed = interrupt_when(_render_args(tmp_path), lambda _: _render_is_writing(tmp_path), signal.SIGKILL)
    assert killed.code == -signal.SIGKILL
    leftovers = hidden_entries(tmp_path)
    assert any(p.name.startswith(".staging.") for p in leftovers) and any(p.suffix == ".mp4" for p in leftovers)
    again = run_lumos3d(*_render_args(tmp_path, frames_count=3))
    assert again.code == 0, again.err
    assert hidden_entries(tmp_path) == []
    assert listing(tmp_path / "frames") == ["00000.png", "00001.png", "00002.png"]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=signal_name)
def test_restore_stopped_while_writing_keeps_the_earlier_outputs(tmp_path, first_restore, photos, random_checkpoint, signum):
    out = shutil.copytree(first_restore, tmp_path / "out")
    before = _contents(out)
    result = interrupt_when(_restore(photos, out / "scene.ply", random_checkpoint), lambda _: _has_staging(out), signum)
    _expect_interrupted(result, signum)
    assert hidden_entries(tmp_path) == []
    assert _contents(out) == before


def test_ctrl_c_during_start_up_ends_in_one_line_and_leaves_nothing(tmp_path, photos, random_checkpoint):
    """The signal lands while the subcommands import torch and pycolmap (whose C extension would
    turn it into an error telling the user to reinstall pycolmap)."""
    out = tmp_path / "new" / "out"
    result = interrupt_when(_restore(photos, out / "scene.ply", random_checkpoint), cli_started, signal.SIGINT)
    _expect_interrupted(result, signal.SIGINT)
    assert list(tmp_path.iterdir()) == []


# -- row 2: re-runs -----------------------------------------------------------------------------------


def test_rerun_with_fewer_views_replaces_the_output_set(tmp_path, buu, first_restore, random_checkpoint):
    out = shutil.copytree(first_restore, tmp_path / "out")
    assert len(list((out / "restored").iterdir())) == 6
    (out / "notes.txt").write_text("the user's own file beside the outputs")
    fewer = _photos(buu, tmp_path / "fewer", ["2.JPG", "4.JPG", "6.JPG"])
    result = run_lumos3d(*_restore(fewer, out / "scene.ply", random_checkpoint))
    assert result.code == 0, result.err
    assert sorted(p.name for p in (out / "restored").iterdir()) == ["2.png", "4.png", "6.png"]
    summary = json.loads((out / "summary.json").read_text())
    cameras = json.loads((out / "cameras.json").read_text())
    assert summary["views"] == ["2.JPG", "4.JPG", "6.JPG"] and len(cameras["frames"]) == 3
    images = (out / "colmap" / "images.txt").read_text()
    assert "1.JPG" not in images and "6.JPG" in images
    assert (out / "notes.txt").read_text() == "the user's own file beside the outputs"
    assert hidden_entries(tmp_path) == []


# -- row 3: the same photo twice -----------------------------------------------------------------------


def test_the_same_photo_twice_is_refused(tmp_path, photos, buu, random_checkpoint, run_cli):
    twice = run_cli(*_restore(photos / "1.JPG", tmp_path / "a" / "scene.ply", random_checkpoint), photos / "1.JPG")
    expect_input_error(twice, f"{photos / '1.JPG'}: the same photo is given twice")
    other = _photos(buu, tmp_path / "other", ["1.JPG"])
    same_name = run_cli("degrade", photos, other / "1.JPG", "-o", tmp_path / "b")
    expect_input_error(same_name, f"{photos / '1.JPG'} and {other / '1.JPG'}: two photos named '1'")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other"]


# -- row 4: an output under a regular file -------------------------------------------------------------


def test_outputs_under_a_regular_file_are_refused_before_any_work(tmp_path, buu, photos, scene_file, random_checkpoint, run_cli):
    blocker = tmp_path / "file"
    blocker.write_text("a regular file")
    cases = [
        (_restore(photos, blocker / "scene.ply", random_checkpoint), "-o", blocker / "scene.ply"),
        (_restore(photos, tmp_path / "out" / "scene.ply", random_checkpoint, "--video", blocker / "v.mp4"), "--video", blocker / "v.mp4"),
        (("eval", buu.parent, "--scenes", "buu", "--out", blocker / "report"), "--out", blocker / "report"),
        (("render", scene_file, "--orbit", 2, "-o", blocker / "frames"), "-o", blocker / "frames"),
        (("render", scene_file, "--orbit", 2, "-o", tmp_path / "frames", "--video", blocker / "v.mp4"), "--video", blocker / "v.mp4"),
        (("degrade", photos, "-o", blocker / "dark"), "-o", blocker / "dark"),
        (("convert", random_checkpoint, "-o", blocker / "w.safetensors"), "-o", blocker / "w.safetensors"),
    ]
    for args, option, path in cases:
        result = run_cli(*args)
        expect_input_error(result, f"{option} {path}: cannot be created because {blocker} is a file")
        assert "render " not in result.err and "load images" not in result.err  # no work started
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


# -- row 6: info on images that will not load ----------------------------------------------------------


def _write_exr_with_nan(path):
    pixels = np.ones((4, 4, 3), np.float32)
    pixels[1, 2, 0] = np.nan
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(4, 4, 3, "float"))
    out.write_image(pixels)
    out.close()


def test_info_deep_names_the_images_that_will_not_load(tmp_path, buu, run_cli):
    folder = _photos(buu, tmp_path / "photos", ["1.JPG", "2.JPG"])
    data = (folder / "2.JPG").read_bytes()
    (folder / "2.JPG").write_bytes(data[: len(data) // 2])
    _write_exr_with_nan(folder / "3.exr")
    cv2.imwrite(str(folder / "4.png"), np.full((10, 40, 3), 128, np.uint8))  # restore refuses it: under one patch
    quick = run_cli("info", folder, "--json")
    assert quick.code == 0, quick.err
    assert json.loads(quick.out)["pixels"].startswith("not decoded; --deep")
    pixels = np.ones((4, 6, 3), np.float32)
    pixels[0, 0] = np.inf
    cv2.imwrite(str(folder / "5.tif"), pixels)  # a float TIFF holding Inf, refused as the EXR is
    (folder / "6.jpg").write_text("no JPEG: its header does not read")
    deep = run_cli("info", folder, "--deep", "--json")
    expect_input_error(deep, "5 of 6 images will not load or restore", "2.JPG (cannot decode as JPG",
                       "3.exr (1 of 48 samples are NaN or Inf", "5.tif (3 of 72 samples", "; and 2 more")
    summary = json.loads(deep.out)
    assert sorted(summary["will_not_load"]) == ["2.JPG", "3.exr", "5.tif", "6.jpg"] and list(summary["too_small"]) == ["4.png"]
    assert summary["will_not_load"]["5.tif"] == "3 of 72 samples are NaN or Inf; clamp or repair the file before use"
    assert summary["count"] == 6 and summary["will_not_load"]["6.jpg"].startswith("cannot read image header")
    assert run_cli("info", folder / "1.JPG", "--deep").code == 0


def test_info_summarises_a_checkpoint_folder_as_restore_takes_it(tmp_path, random_checkpoint, run_cli):
    folder = tmp_path / "step_3"
    folder.mkdir()
    shutil.copy(random_checkpoint, folder / "model.safetensors")
    result = run_cli("info", folder, "--json")
    assert result.code == 0, result.err
    assert json.loads(result.out)["format"] == "lumos3d"


# -- rows 7, 8: non-finite checkpoints and scenes ------------------------------------------------------


def test_a_checkpoint_with_nan_weights_is_refused_by_info_convert_and_restore(tmp_path, photos, run_cli):
    weights = tmp_path / "nan.safetensors"
    save_checkpoint(build_model("tiny", seed=0), weights, {})  # it refuses to write NaN: damaged afterwards
    with safe_open(str(weights), "pt") as file:
        metadata, tensors = file.metadata(), {key: file.get_tensor(key) for key in file.keys()}
    name, tensor = next((n, t) for n, t in tensors.items() if t.is_floating_point() and t.numel() > 4)
    tensor.view(-1)[:3] = float("nan")
    save_file(tensors, str(weights), metadata=metadata)
    fragment = f"{weights}: tensor {name}: 3 of {tensor.numel()} values are NaN or Inf"
    expect_input_error(run_cli("info", weights), fragment)
    expect_input_error(run_cli("convert", weights, "-o", tmp_path / "copy.safetensors"), fragment)
    expect_input_error(run_cli(*_restore(photos, tmp_path / "out" / "scene.ply", weights)), fragment)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nan.safetensors"]


def test_render_of_a_scene_holding_nan_names_the_file(tmp_path, scene_file, run_cli):
    scene = tmp_path / "nan.ply"
    data = bytearray(scene_file.read_bytes())
    start = data.index(b"end_header\n") + len(b"end_header\n")
    data[start + 4 : start + 8] = struct.pack("<f", float("nan"))  # y of the first Gaussian
    scene.write_bytes(bytes(data))
    result = run_cli("render", scene, "--orbit", 2, "-o", tmp_path / "frames")
    expect_input_error(result, f"{scene}: 1 value(s) no scene can use, NaN, Inf or log-scales above 88.7 (y: 1); correct or drop")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nan.ply"]


# -- row 9: messages name the user's path, not a temporary one ------------------------------------------


def test_degrade_output_messages_name_the_users_path(tmp_path, buu, run_cli):
    photo = buu / "low" / "1.JPG"
    for target, fragment in [("x.jpg", "JPEG holds 8 bits only; use .png"), ("x.tif", "cannot write '.tif' files")]:
        result = run_cli("degrade", photo, "-o", tmp_path / target, "--bit-depth", 16)
        expect_input_error(result, f"{tmp_path / target}: {fragment}")
        assert ".tmp" not in result.err
    assert list(tmp_path.iterdir()) == []


# -- row 17: photos of different sizes -----------------------------------------------------------------


@pytest.fixture(scope="module")
def mixed_sizes_restore(tmp_path_factory, buu):
    """`lumos3d restore` (the bundled model, structure-from-motion) of buu's photos 1-7 as they are
    (500x375), 7 once more centre-cropped to 300x375 (the same camera and viewpoint, a narrower
    view) and 8 shrunk to 400x300 (the same view, fewer pixels)."""
    folder = tmp_path_factory.mktemp("mixed") / "photos"
    folder.mkdir()
    for number in range(1, 8):
        shutil.copy(buu / "low" / f"{number}.JPG", folder / f"{number}.JPG")
    photo7 = cv2.imread(str(buu / "low" / "7.JPG"))
    cv2.imwrite(str(folder / "7crop.png"), photo7[:, 100:400])
    cv2.imwrite(str(folder / "8.png"), cv2.resize(cv2.imread(str(buu / "low" / "8.JPG")), (400, 300),
                                                  interpolation=cv2.INTER_AREA))
    out = folder.parent / "out"
    result = run_lumos3d("restore", folder, "-o", out / "scene.ply", "--geometry", "sfm", "--refine-steps", 0)
    assert result.code == 0, result.err
    sizes = {path.name: (cv2.imread(str(path)).shape[1], cv2.imread(str(path)).shape[0]) for path in folder.iterdir()}
    return out, sizes, result


def _psnr(a, b):
    return 10 * np.log10(1 / np.mean((a.astype(np.float64) / 255 - b.astype(np.float64) / 255) ** 2))


def test_photos_of_different_sizes_are_restored_each_at_its_own_size(mixed_sizes_restore):
    out, sizes, result = mixed_sizes_restore
    assert sizes["7crop.png"] == (300, 375) and sizes["8.png"] == (400, 300) and sizes["1.JPG"] == (500, 375)
    assert "2 of 9 photos differ in size from 500x375 (7crop.png, 8.png)" in result.err
    restored = {path.stem: cv2.imread(str(path)) for path in (out / "restored").iterdir()}
    assert {stem: (image.shape[1], image.shape[0]) for stem, image in restored.items()} == {
        name.split(".")[0]: size for name, size in sizes.items()}
    frames = {frame["file_path"]: frame for frame in json.loads((out / "cameras.json").read_text())["frames"]}
    assert sorted(frames) == sorted(sizes)
    colmap = (out / "colmap" / "cameras.txt").read_text().splitlines()
    colmap_sizes = sorted((int(line.split()[2]), int(line.split()[3])) for line in colmap if line and line[0] != "#")
    assert colmap_sizes == sorted(sizes.values())
    for name, (width, height) in sizes.items():
        frame = frames[name]
        assert (frame["w"], frame["h"]) == (width, height), name
        # structure-from-motion saw each photo at its own aspect ratio with a centred pinhole:
        # square pixels and the principal point in the middle of the photo, not of a stretched copy
        assert frame["cx"] == pytest.approx(width / 2) and frame["cy"] == pytest.approx(height / 2), name
        assert frame["fl_y"] == pytest.approx(frame["fl_x"], rel=1e-9), name
    # A crop keeps the focal length in pixels; shrinking by 0.8 scales it by 0.8.
    assert frames["7crop.png"]["fl_x"] == pytest.approx(frames["7.JPG"]["fl_x"], rel=0.03)
    assert frames["8.png"]["fl_x"] == pytest.approx(0.8 * frames["1.JPG"]["fl_x"], rel=0.03)
    crop_pose, full_pose = (np.array(frames[name]["transform_matrix"]) for name in ("7crop.png", "7.JPG"))
    angle = np.degrees(np.arccos(np.clip((np.trace(crop_pose[:3, :3].T @ full_pose[:3, :3]) - 1) / 2, -1, 1)))
    assert angle < 1.0
    # The crop's restored view is the middle of the full photo's restored view, not a squeezed copy.
    middle = restored["7"][:, 100:400]
    assert _psnr(restored["7crop"], middle) > 25
    squeezed = cv2.resize(restored["7"], (300, 375), interpolation=cv2.INTER_AREA)
    assert _psnr(restored["7crop"], squeezed) < _psnr(restored["7crop"], middle) - 5
    summary = json.loads((out / "summary.json").read_text())
    assert summary["geometry"]["source"] == "sfm" and summary["geometry"]["registered_views"] == 9
    assert cv2.imread(str(out / "contact_sheet.png")) is not None


def test_a_restore_of_photos_of_different_sizes_renders_and_opens_in_the_viewer(tmp_path, mixed_sizes_restore, run_cli):
    out, sizes, _ = mixed_sizes_restore
    scene = shutil.copytree(out, tmp_path / "out")
    poses = run_cli("render", scene / "scene.ply", "--poses", scene / "cameras.json", "-o", tmp_path / "frames",
                        "--width", 200)
    assert poses.code == 0, poses.err
    assert len(list((tmp_path / "frames").glob("*.png"))) == len(sizes)
    # without --width/--height every camera renders at its own size, in cameras.json's order
    own = run_cli("render", scene / "scene.ply", "--poses", scene / "cameras.json", "-o", tmp_path / "own")
    assert own.code == 0, own.err
    order = [frame["file_path"] for frame in json.loads((scene / "cameras.json").read_text())["frames"]]
    written = [cv2.imread(str(path)).shape[1::-1] for path in sorted((tmp_path / "own").glob("*.png"))]
    assert written == [sizes[name] for name in order]
    orbit = run_cli("render", scene / "scene.ply", "--orbit", 2, "-o", tmp_path / "orbit", "--width", 100)
    assert orbit.code == 0, orbit.err
    viewer = load_viewer_scene(scene)
    assert sorted(viewer.cameras.sizes) == sorted(sizes.values()) and viewer.notes == []


def test_metrics_against_a_featureless_reference_are_null_in_strict_json(tmp_path, buu, random_checkpoint, run_cli):
    """A black reference has no detail (sharpness undefined) and one grey (PSNR at its mean
    undefined): the files and --json stay strict JSON, the values null, and a warning says so."""
    photos = _photos(buu, tmp_path / "photos", ["1.JPG", "2.JPG"])
    black = tmp_path / "black"
    black.mkdir()
    for name in ("1.png", "2.png"):
        cv2.imwrite(str(black / name), np.zeros((375, 500, 3), np.uint8))
    result = run_cli(*_restore(photos, tmp_path / "out" / "scene.ply", random_checkpoint, "--reference", black, "--json"))
    assert result.code == 0, result.err
    assert "summary.json:" in result.err and "not finite, written as null" in result.err

    def refuse(constant):
        raise AssertionError(f"not strict JSON: {constant}")

    for text in (result.out, (tmp_path / "out" / "summary.json").read_text()):
        views = json.loads(text, parse_constant=refuse)["metrics"]["views"]
        assert views["1.JPG"]["sharpness"] is None and isinstance(views["1.JPG"]["psnr"], float)


def test_info_summarises_a_bundled_model_by_name(run_cli):
    result = run_cli("info", "over-exposure", "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert summary["format"] == "lumos3d" and summary["path"].endswith("lumos3d-over-exposure.safetensors")


def test_photos_with_nothing_in_them_add_nothing_to_the_scene(tmp_path, buu, run_cli):
    """All-black and all-white photos among real ones: their made-up depth and colours are not
    fused (they laid black and white wedges over the other views, one at 15 dB against the run
    without them), and their own views stay the photos they are."""
    clean = _photos(buu, tmp_path / "clean", ["1.JPG", "4.JPG", "7.JPG", "10.JPG", "13.JPG", "16.JPG"])
    mixed = tmp_path / "mixed"
    shutil.copytree(clean, mixed)
    cv2.imwrite(str(mixed / "z0.png"), np.zeros((375, 500, 3), np.uint8))
    cv2.imwrite(str(mixed / "z1.png"), np.full((375, 500, 3), 255, np.uint8))
    options = ("--geometry", "network", "--preset", "fast", "--refine-steps", 0)
    for folder in (clean, mixed):
        result = run_cli("restore", folder, "-o", tmp_path / f"out-{folder.name}" / "scene.ply", *options)
        assert result.code == 0, result.err
    restored = {folder: {path.stem: cv2.imread(str(path)).astype(np.float64) / 255
                         for path in (tmp_path / f"out-{folder}" / "restored").glob("*.png")} for folder in ("clean", "mixed")}
    assert restored["mixed"]["z0"].max() == 0 and restored["mixed"]["z1"].min() == 1
    for name, view in restored["clean"].items():
        assert peak_signal_noise_ratio(view, restored["mixed"][name], data_range=1) > 22, name


def test_an_interrupted_evaluation_leaves_no_work_folder_of_structure_from_motion(tmp_path, buu, random_checkpoint):
    """Ctrl-C while structure-from-motion ran beside the network left its work folder (the
    photos as BMPs and COLMAP's database, 8-14 MB) in the temporary folder for good: the script
    ends the process before the thread's own cleanup."""
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    stopped = interrupt_when(("eval", buu.parent, "--scenes", "buu", "--out", tmp_path / "report", "--checkpoint",
                              random_checkpoint, "--preset", "fast", "--max-views", 6, "--refine-steps", 0),
                             lambda _: any(temporary.glob("lumos3d-sfm-*/images")), signal.SIGINT,
                             env={"TMPDIR": str(temporary)})
    assert stopped.code == 130, stopped.err[-3000:]
    assert sorted(p.name for p in temporary.iterdir() if p.name.startswith("lumos3d-sfm-")) == []


def test_views_no_gaussian_covers_are_warned_of(tmp_path, photos, random_checkpoint, run_cli):
    """--max-gaussians 1: every restored view one flat colour, exit 0 and not a word."""
    result = run_cli(*_restore(photos, tmp_path / "out" / "scene.ply", random_checkpoint, "--max-gaussians", 1))
    assert result.code == 0, result.err
    assert "6 view(s) are mostly uncovered: no Gaussian covers 1.JPG (" in " ".join(result.err.split())
    plain = run_cli(*_restore(photos, tmp_path / "plain" / "scene.ply", random_checkpoint))
    assert plain.code == 0 and "mostly" not in plain.err


def test_a_subset_of_views_always_holds_a_photo_with_content(tmp_path, buu, random_checkpoint, run_cli):
    """Two black photos around one real one, two views through the network: the even subset
    took both black ones, and the restore ended in "fuse_views selects none of the network's views"."""
    photos = tmp_path / "photos"
    photos.mkdir()
    cv2.imwrite(str(photos / "a.png"), np.zeros((375, 500, 3), np.uint8))
    shutil.copy(buu / "low" / "1.JPG", photos / "b.JPG")
    cv2.imwrite(str(photos / "c.png"), np.zeros((375, 500, 3), np.uint8))
    result = run_cli("restore", photos, "-o", tmp_path / "out" / "scene.ply", "--checkpoint", random_checkpoint,
                     "--geometry", "network", "--max-views", 2, "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    assert "b.JPG" in json.loads(result.out)["network_views"]


def test_a_signal_that_lands_as_the_handlers_come_off_exits_as_interrupted(monkeypatch, capsys):
    """torchrun's SIGTERM to the ranks could land after the command returned, while the CLI's
    handlers were being removed: the Interrupted it raised escaped `main` as a raw traceback."""
    import contextlib
    import signal

    from lumos3d_cli.cli import app
    from lumos3d_cli.errors import Interrupted

    @contextlib.contextmanager
    def late_signal():
        yield lambda: None
        raise Interrupted(signal.SIGTERM)

    monkeypatch.setattr(app, "signals_raise_interrupted", late_signal)
    assert app.main(["info", "--help"]) == 128 + signal.SIGTERM
    assert "SIGTERM" in capsys.readouterr().err
