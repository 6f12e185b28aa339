"""No command deletes or overwrites a file it did not write, and inputs are never outputs (issue 38,
rows 1-4, 8, 11): the real commands in child processes, and every user file checked byte by byte
afterwards. Refusals come before any work: a garbage checkpoint, which would be the first thing
to fail once the work starts, is not what they complain about."""

import json
import shutil
from pathlib import Path

import numpy as np

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.colmap import read_colmap_model, write_colmap_model
from lumos3d_cli.io.image_write import write_image
from lumos3d_cli.io.manifest import MANIFEST_NAME, Manifest
from lumos3d_cli.io.ply import write_ply

from assertions import expect_input_error
from factories import random_gaussians
from output_files import PHOTOS, copy_photos, restore_args, snapshot
from processes import run_lumos3d


def _nerfstudio_layout(buu, root):
    """d/images (the photos) and d/colmap/{database.db, sparse/0} (their COLMAP model)."""
    photos = copy_photos(buu, root / "images")
    cameras = read_colmap_model(buu / "colmap_text")
    chosen = [cameras.names.index(name) for name in PHOTOS]
    model = root / "colmap" / "sparse" / "0"
    write_colmap_model(model, Cameras(cameras.extrinsics[chosen], cameras.intrinsics[chosen],
                                      [cameras.sizes[i] for i in chosen], PHOTOS))
    (root / "colmap" / "database.db").write_bytes(b"SQLite format 3\0 the user's feature matches")
    return photos, model


def test_row1_poses_in_the_colmap_folder_beside_the_output_survive(tmp_path, buu, random_checkpoint, garbage_checkpoint):
    d = tmp_path / "d"
    photos, model = _nerfstudio_layout(buu, d)
    before = snapshot(d)
    refused = run_lumos3d(*restore_args(photos, d / "scene.ply", garbage_checkpoint, "--poses", model))
    expect_input_error(refused, f"{d / 'colmap'}: would hold the outputs, but it holds the input {model}")
    assert snapshot(d) == before
    done = run_lumos3d(*restore_args(photos, d / "lumos3d" / "scene.ply", random_checkpoint, "--poses", model))
    assert done.code == 0, done.err
    after = snapshot(d)
    assert {name: after[name] for name in before} == before
    assert (d / "lumos3d" / "colmap" / "images.txt").is_file() and len(list((d / "lumos3d" / "restored").iterdir())) == 6


def test_row2_photos_in_a_folder_named_restored_are_never_outputs(tmp_path, buu, random_checkpoint, garbage_checkpoint):
    photos = copy_photos(buu, tmp_path / "p" / "restored")
    before = snapshot(tmp_path)
    result = run_lumos3d(*restore_args(photos, tmp_path / "p" / "scene.ply", garbage_checkpoint))
    expect_input_error(result, f"{photos}: would hold the outputs, but it holds the input")
    assert snapshot(tmp_path) == before


def test_row3_the_users_files_in_restored_or_colmap_refuse_the_run_and_survive(tmp_path, buu, earlier_restore, garbage_checkpoint):
    photos = copy_photos(buu, tmp_path / "photos")
    for folder, name in (("restored", "notes.txt"), ("colmap", "database.db")):
        out = tmp_path / f"fresh-{folder}"
        (out / folder).mkdir(parents=True)
        (out / folder / name).write_text("the user's")
        result = run_lumos3d(*restore_args(photos, out / "scene.ply", garbage_checkpoint))
        expect_input_error(result, f"{out / folder / name}: exists and was not written by lumos3d")
        assert snapshot(out) == {f"{folder}/{name}": b"the user's"}
    out = shutil.copytree(earlier_restore, tmp_path / "earlier")  # lumos3d's outputs with a user's file among them
    (out / "restored" / "notes.txt").write_text("the user's")
    before = snapshot(out)
    result = run_lumos3d(*restore_args(photos, out / "scene.ply", garbage_checkpoint))
    expect_input_error(result, f"{out / 'restored' / 'notes.txt'}: exists and was not written by lumos3d")
    assert snapshot(out) == before


def test_row3_a_rerun_replaces_only_lumos3ds_own_earlier_outputs(tmp_path, buu, random_checkpoint, earlier_restore):
    out = shutil.copytree(earlier_restore, tmp_path / "out")
    (out / "notes.txt").write_text("the user's, beside the outputs")
    (out / "restored" / "1.png").write_bytes((out / "restored" / "1.png").read_bytes() + b"edited")
    edited = run_lumos3d(*restore_args(copy_photos(buu, tmp_path / "again"), out / "scene.ply", random_checkpoint))
    expect_input_error(edited, f"{out / 'restored' / '1.png'}: was changed since lumos3d wrote it")
    (out / "restored" / "1.png").unlink()
    fewer = copy_photos(buu, tmp_path / "fewer", ["2.JPG", "4.JPG"])
    result = run_lumos3d(*restore_args(fewer, out / "scene.ply", random_checkpoint))
    assert result.code == 0, result.err
    assert sorted(p.name for p in (out / "restored").iterdir()) == ["2.png", "4.png"]
    assert (out / "notes.txt").read_text() == "the user's, beside the outputs"
    manifest = Manifest.read(out)
    assert all(manifest.owns(out / name) for name in manifest.files) and "notes.txt" not in manifest.files


def test_row4_degrade_never_writes_over_its_inputs(tmp_path, buu):
    pngs = tmp_path / "pngs"
    pngs.mkdir()
    for name in ("1", "2"):
        write_image(pngs / f"{name}.png", np.full((20, 30, 3), 0.6, np.float32))
    before = snapshot(tmp_path)
    expect_input_error(run_lumos3d("degrade", pngs / "1.png", "-o", pngs / "1.png"), f"{pngs / '1.png'}: is an input")
    expect_input_error(run_lumos3d("degrade", pngs, "-o", pngs), f"{pngs}: is the input folder {pngs}")
    expect_input_error(run_lumos3d("degrade", pngs, "-o", pngs / "dark"), "lies inside the input folder")
    # photos given one by one: not into their own folder (1.png beside 1.JPG made it unreadable)...
    expect_input_error(run_lumos3d("degrade", pngs / "1.png", pngs / "2.png", "-o", pngs), f"{pngs}: is the input folder")
    # ...but a folder inside it is fine (cd photos; degrade *.JPG -o dark/)
    assert run_lumos3d("degrade", pngs / "1.png", pngs / "2.png", "-o", pngs / "dark").code == 0
    shutil.rmtree(pngs / "dark")
    link = tmp_path / "link.png"
    link.symlink_to(pngs / "2.png")
    expect_input_error(run_lumos3d("degrade", pngs / "2.png", "-o", link), f"{link}: is an input")
    link.unlink()
    assert snapshot(tmp_path) == before
    (tmp_path / "dark").mkdir()
    (tmp_path / "dark" / "1.png").write_text("the user's")
    expect_input_error(run_lumos3d("degrade", pngs, "-o", tmp_path / "dark"), "dark/1.png: exists and was not written by lumos3d")
    (tmp_path / "dark" / "1.png").unlink()
    for _ in range(2):  # a re-run replaces its own outputs
        assert run_lumos3d("degrade", pngs, "-o", tmp_path / "dark").code == 0
    assert sorted(p.name for p in (tmp_path / "dark").iterdir()) == [MANIFEST_NAME, "1.png", "2.png", "degradation.json"]
    assert run_lumos3d("degrade", pngs / "1.png", "-o", pngs / "1-dark.png").code == 0  # beside its input: fine
    assert snapshot(pngs)["1.png"] == before["pngs/1.png"]


def test_row8_restore_into_its_photo_folder_is_refused(tmp_path, buu, garbage_checkpoint):
    photos = copy_photos(buu, tmp_path / "P")
    before = snapshot(tmp_path)
    result = run_lumos3d(*restore_args(photos, photos / "scene.ply", garbage_checkpoint))
    expect_input_error(result, f"-o {photos}: is the input folder {photos}")
    assert snapshot(tmp_path) == before


def test_row11_a_file_named_restored_in_the_output_folder_is_refused_before_any_work(tmp_path, buu, garbage_checkpoint):
    photos = copy_photos(buu, tmp_path / "photos")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "restored").write_text("the user's file")
    result = run_lumos3d(*restore_args(photos, tmp_path / "out" / "scene.ply", garbage_checkpoint))
    expect_input_error(result, f"{tmp_path / 'out' / 'restored'}: is a file where lumos3d writes its folder restored/")
    assert snapshot(tmp_path / "out") == {"restored": b"the user's file"}


def test_render_eval_and_convert_never_write_over_the_users_files(tmp_path, buu):
    scene = tmp_path / "scene.ply"
    write_ply(scene, random_gaussians(50, 0))
    frames = tmp_path / "frames"
    frames.mkdir()
    (frames / "00001.png").write_text("the user's")
    expect_input_error(run_lumos3d("render", scene, "--orbit", 3, "-o", frames, "--width", 32),
                       f"{frames / '00001.png'}: exists and was not written by lumos3d")
    model = tmp_path / "model"
    cameras = read_colmap_model(buu / "colmap_text")
    write_colmap_model(model, cameras[[0, 1]])
    expect_input_error(run_lumos3d("render", scene, "--poses", model, "-o", model), f"{model}: is the input folder")
    (tmp_path / "report").mkdir()
    (tmp_path / "report" / "metrics.json").write_text("the user's")
    expect_input_error(run_lumos3d("eval", buu.parent, "--scenes", "buu", "--out", tmp_path / "report"),
                       "metrics.json: exists and was not written by lumos3d")
    (tmp_path / "mine.splat").write_text("the user's")
    expect_input_error(run_lumos3d("convert", scene, "-o", tmp_path / "mine.splat"), "mine.splat: exists and was not written by lumos3d")
    assert (frames / "00001.png").read_text() == (tmp_path / "report" / "metrics.json").read_text() == "the user's"
    assert (tmp_path / "mine.splat").read_text() == "the user's"


def test_row8_an_earlier_restores_contact_sheet_among_the_photos_is_no_photo(tmp_path, buu, random_checkpoint):
    photos = copy_photos(buu, tmp_path / "P", ["1.JPG", "2.JPG", "3.JPG"])
    first = run_lumos3d(*restore_args(photos / "1.JPG", photos / "scene.ply", random_checkpoint, photos / "2.JPG",
                                      photos / "3.JPG"))
    assert first.code == 0, first.err  # the photos named one by one: the folder is no input folder
    assert (photos / "contact_sheet.png").is_file()
    again = run_lumos3d(*restore_args(photos, tmp_path / "R" / "scene.ply", random_checkpoint, "--json"))
    assert again.code == 0, again.err
    assert json.loads(again.out)["views"] == ["1.JPG", "2.JPG", "3.JPG"]
    # the Python API's `load_images` and `degrade` read the same photos (they took the sheet for one)
    import lumos3d_cli

    assert [path.name for path in lumos3d_cli.load_images(photos).paths] == ["1.JPG", "2.JPG", "3.JPG"]
    degraded = run_lumos3d("degrade", photos, "-o", tmp_path / "D", "--json")
    assert degraded.code == 0, degraded.err
    assert [Path(image["input"]).name for image in json.loads(degraded.out)["images"]] == ["1.JPG", "2.JPG", "3.JPG"]
