import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import OpenImageIO as oiio
import pytest

from lumos3d_cli import __version__
from lumos3d_cli.io.ply import write_ply

from factories import random_gaussians
from assertions import expect_input_error
from output_files import listing


def test_help_lists_every_command_with_examples(run_cli):
    result = run_cli("--help")
    assert result.code == 0
    assert "Examples" in result.out
    for command in ("degrade", "info", "render", "train", "restore", "eval", "convert", "view"):
        assert f" {command} " in result.out


def test_a_named_subcommand_imports_only_its_own_module(tmp_path):
    # Start-up time: `info` must not wait for the evaluation's, the viewer's or training's imports.
    probe = (
        "import sys; from lumos3d_cli.cli.app import main; "
        f"code = main(['info', {str(tmp_path / 'missing')!r}]); "
        "print(code, sorted(m for m in sys.modules if m.startswith('lumos3d_cli.cli.')))"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    code, imported = result.stdout.split(" ", 1)
    assert code == "2"
    assert "lumos3d_cli.cli.info" in imported
    for other in ("eval", "restore", "train", "view", "convert"):
        assert f"lumos3d_cli.cli.{other}'" not in imported


def test_version(run_cli):
    result = run_cli("--version")
    assert result.code == 0 and result.out.strip() == f"lumos3d {__version__}"


def test_usage_errors_exit_with_2(run_cli):
    assert run_cli("degrade").code == 2
    assert run_cli("no-such-command").code == 2


def _copy_images(source, target, count):
    target.mkdir()
    for path in sorted(source.iterdir())[:count]:
        shutil.copy(path, target / path.name)
    return target


def test_degrade_writes_every_image_and_a_record(run_cli, buu, tmp_path):
    inputs = _copy_images(buu / "high", tmp_path / "high", 3)
    result = run_cli("degrade", inputs, "-o", tmp_path / "dark", "--seed", 3, "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert summary["count"] == 3 and summary["mode"] == "low-light" and summary["shared_parameters"]
    written = listing(tmp_path / "dark")
    assert written == sorted([f"{p.stem}.png" for p in inputs.iterdir()] + ["degradation.json"])
    first = cv2.imread(str(tmp_path / "dark" / "1.png"))
    original = cv2.imread(str(inputs / "1.JPG"))
    assert first.shape == original.shape and first.mean() < 0.3 * original.mean()
    exposures = {record["exposure"] for record in summary["images"]}
    assert len(exposures) == 1 and 0.05 <= exposures.pop() <= 0.1
    again = run_cli("degrade", inputs, "-o", tmp_path / "again", "--seed", 3)
    assert again.code == 0
    assert (tmp_path / "again" / "1.png").read_bytes() == (tmp_path / "dark" / "1.png").read_bytes()


def test_degrade_over_exposure_16_bit_per_image(run_cli, buu, tmp_path):
    inputs = _copy_images(buu / "high", tmp_path / "high", 2)
    result = run_cli("degrade", inputs, "-o", tmp_path / "bright", "--mode", "over-exposure",
                     "--per-image", "--bit-depth", "16", "--noise", "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert len({r["exposure"] for r in summary["images"]}) == 2 and "shot_noise" in summary["images"][0]
    assert summary["bit_depth"] == 16 and json.loads((tmp_path / "bright" / "degradation.json").read_text())["bit_depth"] == 16
    image = cv2.imread(str(tmp_path / "bright" / "1.png"), cv2.IMREAD_UNCHANGED)
    assert image.dtype == np.uint16 and image.mean() / 65535 > 0.7


def test_degrade_with_the_camera_pipeline_records_its_draws(run_cli, buu, tmp_path):
    inputs = _copy_images(buu / "high", tmp_path / "high", 1)
    result = run_cli("degrade", inputs, "-o", tmp_path / "dark", "--noise", "--colour-cast", "1.25",
                     "--jpeg-quality", "80", "--json")
    assert result.code == 0, result.err
    record = json.loads(result.out)["images"][0]
    assert record["jpeg_quality"] == 80 and record["colour_cast"][1] == 1
    assert all(0.8 <= gain <= 1.25 for gain in record["colour_cast"])
    plain = run_cli("degrade", inputs, "-o", tmp_path / "plain", "--noise")
    assert plain.code == 0
    assert cv2.imread(str(tmp_path / "dark" / "1.png")).shape == cv2.imread(str(tmp_path / "plain" / "1.png")).shape


def test_a_jpeg_output_is_compressed_once_at_the_quality_asked(run_cli, buu, tmp_path):
    """`-o dark.jpg --jpeg-quality 50` compressed at 50 in the degradation, then again at 95 when
    writing; without --jpeg-quality the file's compression at 95 went unrecorded."""
    inputs = _copy_images(buu / "high", tmp_path / "high", 1)
    result = run_cli("degrade", inputs, "-o", tmp_path / "q50.jpg", "--jpeg-quality", "50", "--json")
    assert result.code == 0, result.err
    assert json.loads(result.out)["images"][0]["jpeg_quality"] == 50
    as_png = run_cli("degrade", inputs, "-o", tmp_path / "q50.png", "--jpeg-quality", "50")
    assert as_png.code == 0, as_png.err  # the degradation's own JPEG round trip, stored losslessly
    assert np.array_equal(cv2.imread(str(tmp_path / "q50.jpg")), cv2.imread(str(tmp_path / "q50.png")))
    default = run_cli("degrade", inputs, "-o", tmp_path / "plain.jpg", "--json")
    summary = json.loads(default.out)
    assert summary["jpeg_quality"] == 95 and summary["images"][0]["jpeg_quality"] == 95


def test_degrade_refuses_seeds_beyond_the_generator_and_jpeg_beyond_its_sizes(run_cli, tmp_path):
    image = tmp_path / "strip.png"
    cv2.imwrite(str(image), np.full((2, 65501, 3), 128, np.uint8))
    for seed in ("-1", str(2**63)):  # -1 gave 2**64 - 1's images; 2**64 an internal error
        expect_input_error(run_cli("degrade", image, "-o", tmp_path / "o", "--seed", seed), f"--seed {seed}", "0 to 2**63 - 1")
    for output, options in (("o.jpg", ()), ("o", ("--jpeg-quality", "90"))):  # internal errors naming a staging file
        result = run_cli("degrade", image, "-o", tmp_path / output, *options)
        expect_input_error(result, f"{image}: 65501x2 pixels; JPEG holds at most 65500 a side")
        assert ".staging" not in result.err
    assert listing(tmp_path) == ["strip.png"]
    wide = tmp_path / "wide.tif"  # libpng's limit of 1,000,000 a side: OpenCV's encoder failed, an internal error
    cv2.imwrite(str(wide), np.full((1, 1_000_001, 3), 128, np.uint8))
    result = run_cli("degrade", wide, "-o", tmp_path / "o")
    expect_input_error(result, f"{wide}: 1000001x1 pixels; a PNG written here holds at most 1,000,000 a side")
    assert listing(tmp_path) == ["strip.png", "wide.tif"]


def test_an_empty_argument_is_refused_not_read_as_the_current_folder(run_cli, tmp_path, monkeypatch):
    """`-o "$OUT"` with OUT unset wrote every output into the current folder; `degrade ""` read it."""
    cv2.imwrite(str(tmp_path / "a.png"), np.full((4, 4, 3), 128, np.uint8))
    monkeypatch.chdir(tmp_path)
    expect_input_error(run_cli("degrade", "a.png", "-o", ""), "an empty argument (after '-o' on the command line")
    expect_input_error(run_cli("degrade", "", "-o", "out"), "an empty argument (after 'degrade'")
    expect_input_error(run_cli("degrade", "a.png", "--output="), "--output=: gives the option an empty value")
    assert listing(tmp_path) == ["a.png"]


def test_degrade_single_file_and_raw(run_cli, shared_data, tmp_path):
    result = run_cli("degrade", shared_data / "raw" / "Blackmagic.dng", "-o", tmp_path / "dark.png", "--quiet")
    assert result.code == 0, result.err
    assert cv2.imread(str(tmp_path / "dark.png")).shape == (2160, 4096, 3)  # the DNG's default crop
    assert listing(tmp_path) == ["dark.png"]


def _write_exr_with_nan(path):
    pixels = np.ones((4, 4, 3), np.float32)
    pixels[1, 2, 0] = np.nan
    spec = oiio.ImageSpec(4, 4, 3, "float")
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), spec)
    out.write_image(pixels)
    out.close()


@pytest.mark.parametrize(
    "make, fragments",
    [
        (lambda d: (d / "empty").mkdir(), ["empty: folder holds no images"]),
        (lambda d: (d / "zero.jpg").write_bytes(b""), ["zero.jpg: file is empty (0 bytes)"]),
        (lambda d: (d / "text.jpg").write_text("not an image"), ["text.jpg: cannot decode as JPG"]),
        (lambda d: (d / "fake.nef").write_bytes(b"II*\x00" + bytes(64)), ["fake.nef: unsupported camera RAW"]),
        (lambda d: _write_exr_with_nan(d / "nan.exr"), ["nan.exr: 1 of 48 samples are NaN or Inf"]),
    ],
    ids=["no-images", "zero-byte", "text-as-jpg", "unsupported-raw", "nan-exr"],
)
def test_degrade_bad_inputs(run_cli, tmp_path, make, fragments):
    bad = tmp_path / "in"
    bad.mkdir()
    make(bad)
    target = next(bad.iterdir())
    result = run_cli("degrade", target, "-o", tmp_path / "out")
    expect_input_error(result, *fragments)
    assert not (tmp_path / "out").exists()


def test_degrade_corrupt_jpeg_among_good_ones_leaves_no_partial_output(run_cli, buu, tmp_path):
    inputs = _copy_images(buu / "high", tmp_path / "in", 3)
    data = (inputs / "1.JPG").read_bytes()
    (inputs / "99.jpg").write_bytes(data[: len(data) // 3])
    result = run_cli("degrade", inputs, "-o", tmp_path / "out")
    expect_input_error(result, "99.jpg: cannot decode as JPG (corrupt, truncated")
    assert not (tmp_path / "out").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]


def _linear(srgb_uint8):
    # IEC 61966-2-1, written out here as the oracle
    x = srgb_uint8.astype(np.float64) / 255
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def test_degrade_exposure_and_gamma_ranges_replace_the_modes(run_cli, buu, tmp_path):
    inputs = _copy_images(buu / "high", tmp_path / "high", 2)
    result = run_cli("degrade", inputs, "-o", tmp_path / "dark", "--exposure", "0.02", "0.03", "--gamma", "1.0", "1.2",
                     "--per-image", "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert summary["exposure_range"] == [0.02, 0.03] and summary["gamma_range"] == [1.0, 1.2]
    assert all(0.02 <= r["exposure"] <= 0.03 and 1.0 <= r["gamma"] <= 1.2 for r in summary["images"])
    # gamma 1: the linear light is the photo's times the exposure
    exact = run_cli("degrade", inputs / "1.JPG", "-o", tmp_path / "third.png", "--exposure", "0.3", "0.3",
                    "--gamma", "1", "1", "--bit-depth", "16")
    assert exact.code == 0, exact.err
    degraded = cv2.imread(str(tmp_path / "third.png"), cv2.IMREAD_UNCHANGED).astype(np.float64) / 65535
    linear = np.where(degraded <= 0.04045, degraded / 12.92, ((degraded + 0.055) / 1.055) ** 2.4)
    assert linear.mean() / _linear(cv2.imread(str(inputs / "1.JPG"))).mean() == pytest.approx(0.3, rel=0.01)
    defaults = json.loads(run_cli("degrade", inputs, "-o", tmp_path / "default", "--json").out)
    assert defaults["exposure_range"] == [0.05, 0.1] and defaults["gamma_range"] == [1.3, 1.4]


def test_degrade_bad_values(run_cli, buu, tmp_path):
    image = buu / "high" / "1.JPG"
    expect_input_error(run_cli("degrade", image, "-o", tmp_path / "o", "--mode", "sunny"), "--mode 'sunny'", "low-light")
    expect_input_error(run_cli("degrade", image, "-o", tmp_path / "o", "--bit-depth", "12"), "--bit-depth 12")
    expect_input_error(run_cli("degrade", image, "-o", tmp_path / "o.jpg", "--bit-depth", "16"), "JPEG holds 8 bits only")
    expect_input_error(run_cli("degrade", buu / "high", "-o", tmp_path / "one.png"), "names one file but there are 25 inputs")
    copy = tmp_path / "photos" / "1.JPG"  # a copy: were the refusal to fail, nothing lands in the shared data
    copy.parent.mkdir()
    copy.write_bytes(image.read_bytes())
    expect_input_error(run_cli("degrade", copy, "-o", copy.with_suffix(".png")), "-o ", "would sit beside 1.JPG")
    assert sorted(p.name for p in copy.parent.iterdir()) == ["1.JPG"]
    link = tmp_path / "links" / "x.JPG"  # a link elsewhere: the twin would sit beside the photo it reaches
    link.parent.mkdir()
    link.symlink_to(copy)
    expect_input_error(run_cli("degrade", link, "-o", copy.with_suffix(".png")), "-o ", "would sit beside 1.JPG")
    assert sorted(p.name for p in copy.parent.iterdir()) == ["1.JPG"]
    for gain in ("0.5", "inf", "nan", "1e+100"):  # 1e100 overflowed into NaN, blamed on a staging file
        expect_input_error(run_cli("degrade", image, "-o", tmp_path / "o", "--colour-cast", gain), f"--colour-cast {gain}",
                           "must be from 1 (no cast) to 100")
    expect_input_error(run_cli("degrade", image, "-o", tmp_path / "o", "--jpeg-quality", "0"), "--jpeg-quality 0", "1 to 100")
    expect_input_error(run_cli("degrade", image, "-o", tmp_path / "o", "--jpeg-quality", "85", "--bit-depth", "16"),
                       "--jpeg-quality 85", "8 bits")
    expect_input_error(run_cli("degrade", image, "-o", tmp_path / "o", "--exposure", "0.5", "0.1"), "--exposure 0.5 0.1", "1e-06 <= low <= high <= 1e+06")
    expect_input_error(run_cli("degrade", image, "-o", tmp_path / "o", "--gamma", "0", "1"), "--gamma 0.0 1.0", "0.01 <= low <= high <= 100")
    # beyond float32: an exposure of 1e308 was Inf, and Inf times a black pixel NaN in the written image
    expect_input_error(run_cli("degrade", image, "-o", tmp_path / "o", "--exposure", "1e308", "1e308"), "--exposure 1e+308 1e+308")
    # an .exr file name is a file, not a folder: refused, as .tif is
    expect_input_error(run_cli("degrade", image, "-o", tmp_path / "o.exr"), "o.exr: cannot write '.exr' files; use .png or .jpg")
    assert not (tmp_path / "o.exr").exists() and not (tmp_path / "o").exists()
    assert not (tmp_path / "o").exists()


def test_info_on_a_scene_file(run_cli, tmp_path):
    gaussians = random_gaussians(100, 2)
    write_ply(tmp_path / "scene.ply", gaussians)
    result = run_cli("info", tmp_path / "scene.ply", "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert summary["count"] == 100 and summary["sh_degree"] == 2 and summary["non_finite_values"] == 0
    assert summary["bounds"]["min"] == pytest.approx(gaussians.means.min(dim=0).values.tolist(), rel=1e-6)
    assert summary["opacity"]["mean"] == pytest.approx(gaussians.opacities.mean().item(), rel=1e-5)
    table = run_cli("info", tmp_path / "scene.ply")
    assert table.code == 0 and "sh_degree" in table.out and "100" in table.out


def test_info_counts_non_finite_values_in_foreign_files(run_cli, tmp_path):
    from plyfile import PlyData, PlyElement

    from lumos3d_cli.io.ply import ply_property_names

    records = np.zeros(4, dtype=[(n, "f4") for n in ply_property_names(0)])
    records["x"][1] = np.nan
    records["rot_0"] = 1
    PlyData([PlyElement.describe(records, "vertex")]).write(str(tmp_path / "bad.ply"))
    summary = json.loads(run_cli("info", tmp_path / "bad.ply", "--json").out)
    assert summary["non_finite_values"] == 1 and summary["count"] == 4


def test_info_on_cameras_images_and_scene_folders(run_cli, shared_data, buu):
    cameras = json.loads(run_cli("info", buu / "transforms_test.json", "--json").out)
    assert cameras["count"] == 3 and cameras["image_sizes"] == {"500x375": 3}
    images = json.loads(run_cli("info", buu / "low", "--json").out)
    assert images["count"] == 25 and images["raw"] == 0 and images["first"] == "1.JPG" and images["last"] == "25.JPG"
    raw = json.loads(run_cli("info", shared_data / "raw" / "Blackmagic.dng", "--json").out)
    assert raw["raw"] == 1 and raw["sizes"] == {"4096x2160": 1} and raw["bit_depths"] == {"16": 1}
    scene = json.loads(run_cli("info", shared_data / "scenes" / "kitchen", "--json").out)
    kinds = [s["kind"] for s in scene["summaries"]]
    assert kinds == ["images", "cameras"] and scene["summaries"][1]["count"] == 17
    lom = json.loads(run_cli("info", buu, "--json").out)  # a LOM scene: the photos of each lighting
    assert [(Path(s["path"]).name, s["count"]) for s in lom["summaries"]] == [("high", 25), ("low", 25), ("over_exp", 25),
                                                                              ("buu", 25)]
    # its transforms splits, read together (frame 1, in two of them, once)
    assert lom["summaries"][-1]["kind"] == "cameras" and lom["summaries"][-1]["format"] == "transforms splits"
    colmap = json.loads(run_cli("info", buu / "colmap_sparse" / "0" / "images.bin", "--json").out)  # not a checkpoint
    assert colmap["kind"] == "cameras" and colmap["format"] == "colmap" and colmap["count"] == 25
    points = json.loads(run_cli("info", buu / "colmap_sparse" / "0" / "points3D.bin", "--json").out)  # read as a checkpoint once
    assert points["kind"] == "cameras" and points["count"] == 25


def test_info_on_a_restore_output_folder_shows_its_scene(run_cli, tmp_path):
    write_ply(tmp_path / "scene.ply", random_gaussians(50, 0))
    cv2.imwrite(str(tmp_path / "contact_sheet.png"), np.zeros((8, 8, 3), np.uint8))
    summary = json.loads(run_cli("info", tmp_path, "--json").out)
    assert summary["kind"] == "gaussians" and summary["count"] == 50  # the contact sheet is no image folder
    # a mesh beside the scene is named and left out; it refused the whole folder
    (tmp_path / "mesh.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n")
    result = run_cli("info", tmp_path, "--json")
    assert result.code == 0 and json.loads(result.out)["count"] == 50, result.err
    assert "mesh.ply: not a 3D Gaussian scene" in result.err and "left out of the summary" in " ".join(result.err.split())


def test_info_on_a_folder_of_weight_files_summarises_each(run_cli, tmp_path):
    """A training run's folder (final.safetensors, selected.safetensors): "holds no images, cameras,
    checkpoint or .ply"."""
    from lumos3d_cli.model.checkpoints import save_checkpoint
    from lumos3d_cli.model.lumos3d import build_model

    for name in ("final.safetensors", "selected.safetensors"):
        save_checkpoint(build_model("tiny", seed=0), tmp_path / name, {"steps": 2})
    result = run_cli("info", tmp_path, "--json")
    assert result.code == 0, result.err
    summaries = json.loads(result.out)["summaries"]
    assert [Path(s["path"]).name for s in summaries] == ["final.safetensors", "selected.safetensors"]
    assert all(s["kind"] == "checkpoint" and s["architecture"] == "tiny" for s in summaries)


def test_info_bad_inputs(run_cli, tmp_path):
    expect_input_error(run_cli("info", tmp_path / "missing.ply"), "missing.ply: no such file or folder")
    (tmp_path / "notes.txt").write_text("hi")
    expect_input_error(run_cli("info", tmp_path / "notes.txt"), "cannot summarise '.txt' files")
    (tmp_path / "empty").mkdir()
    expect_input_error(run_cli("info", tmp_path / "empty"), "nothing to summarise")
    (tmp_path / "broken.ply").write_text("ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nend_header\n")
    expect_input_error(run_cli("info", tmp_path / "broken.ply"), "missing vertex properties")


def test_console_script_and_debug_traceback(tmp_path):
    script = shutil.which("lumos3d", path=os.path.dirname(sys.executable))
    assert script is not None
    quiet = subprocess.run([script, "info", str(tmp_path / "missing")], capture_output=True, text=True)
    assert quiet.returncode == 2 and "Traceback" not in quiet.stderr and "missing: no such file" in quiet.stderr
    debug = subprocess.run([script, "info", str(tmp_path / "missing"), "--debug"], capture_output=True, text=True)
    assert debug.returncode != 0 and "Traceback" in debug.stderr
    module = subprocess.run([sys.executable, "-m", "lumos3d_cli", "--version"], capture_output=True, text=True)
    assert module.returncode == 0 and module.stdout.startswith("lumos3d ")


def test_usage_errors_are_one_line_naming_the_option_and_the_help(run_cli):
    for args, message in (
        (("restore", "photos", "-o", "out/scene.ply", "--max-views", "abc"), "Invalid value for '--max-views'"),
        (("restore", "-o", "out/scene.ply"), "Missing argument 'photos'"),
        (("restore", "photos", "-o", "out/scene.ply", "--bogus"), "No such option: --bogus"),
        (("bogus",), "No such command 'bogus'"),
    ):
        result = run_cli(*args)
        assert result.code == 2 and result.err.count("\n") == 1, result.err
        assert result.err.startswith(f"error: {message}") and "--help'" in result.err


def test_paths_and_values_are_printed_as_typed_never_read_as_markup(run_cli, tmp_path):
    folder = tmp_path / "[bold]IMG [edited]"
    folder.mkdir()
    result = run_cli("info", folder)  # read as markup before: printed "IMG" in bold, the brackets lost
    assert result.code == 2 and f"error: {folder}: holds no images" in result.err, result.err
    result = run_cli("info", tmp_path, "IMG [edited].jpg")
    assert result.code == 2 and "(IMG [edited].jpg)" in result.err, result.err
    result = run_cli("[/x]")
    assert result.code == 2 and "No such command '[/x]'" in result.err, result.err
