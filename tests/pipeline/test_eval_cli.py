import csv
import json
import shutil

import cv2
import numpy as np
import pytest
from assertions import expect_input_error


def test_eval_on_buu_writes_the_report(run_cli, buu, tmp_path, random_checkpoint):
    result = run_cli("eval", buu.parent, "--scenes", "buu", "--checkpoint", random_checkpoint, "--out", tmp_path / "report",
                     "--max-views", 5, "--geometry", "network", "--refine-steps", 0)
    assert result.code == 0, result.err
    assert "gamma" in result.out and "18.65" in result.out and "mean" in result.out
    report = json.loads((tmp_path / "report" / "metrics.json").read_text())
    rows = {(r["scene"], r["method"]): r for r in report["rows"]}
    assert rows[("buu", "gamma")]["psnr"] == rows[("mean", "gamma")]["psnr"]
    assert abs(rows[("buu", "gamma")]["ssim"] - 0.870) < 1e-3
    assert report["frames"]["buu"]["test"] == ["1", "13", "19"] and report["frames"]["buu"]["views_used"] == 5
    assert report["fill_unobserved"] and report["uncovered"]["buu"]["filled"]
    assert all(0 <= value <= 1 for value in report["uncovered"]["buu"]["unobserved_fraction"])
    # The gamma curve aims at a mean of 0.45 where buu's ground truth is brighter: matching the
    # exposure (GT-mean PSNR) scores it higher.
    assert rows[("buu", "gamma")]["psnr_gt_mean"] > rows[("buu", "gamma")]["psnr"]
    with open(tmp_path / "report" / "metrics.csv") as handle:
        csv_rows = list(csv.DictReader(handle))
        assert len(csv_rows) == 4 and float(csv_rows[0]["psnr_gt_mean"]) > 0
    sheet = cv2.imread(str(tmp_path / "report" / "contact_sheet_buu.png"))
    assert sheet is not None and sheet.shape[0] > 3 * 200
    cameras = report["cameras"]["buu"]
    assert cameras["pairs"] == 10 and 0 <= cameras["auc_30"] <= 1 and 0 <= cameras["rotation_error_median"] <= 180
    assert "buu cameras (network, 10 view pairs)" in result.out


def test_holdout_over_exposure(run_cli, buu, tmp_path, random_checkpoint):
    result = run_cli("eval", buu, "--mode", "over-exposure", "--protocol", "holdout", "--checkpoint", random_checkpoint,
                     "--out", tmp_path / "report", "--max-views", 5, "--geometry", "network", "--black-unobserved",
                     "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    report = json.loads(result.out)
    assert report["protocol"] == "holdout" and report["mode"] == "over-exposure"
    assert not report["fill_unobserved"] and len(report["uncovered"]["buu"]["unobserved_fraction"]) == 3
    gamma = next(r for r in report["rows"] if r["method"] == "gamma")
    assert abs(gamma["psnr"] - 15.47) < 0.01


def test_eval_bad_inputs(run_cli, lom_copy, tmp_path, random_checkpoint):
    out = tmp_path / "report"
    (lom_copy / "high" / "13.JPG").unlink()
    expect_input_error(run_cli("eval", lom_copy.parent, "--checkpoint", random_checkpoint, "--out", out),
                  "test frame '13' has no normal-light photo in high/")
    cv2.imwrite(str(lom_copy / "high" / "13.JPG"), np.zeros((100, 120, 3), np.uint8))
    expect_input_error(run_cli("eval", lom_copy.parent, "--checkpoint", random_checkpoint, "--out", out, "--max-views", 4,
                                 "--geometry", "network"),
                  "high/13.JPG: 120x100, but the scene's photos are 500x375")
    expect_input_error(run_cli("eval", lom_copy.parent, "--scenes", "bike", "--checkpoint", random_checkpoint, "--out", out),
                  "no LOM scene(s) bike")
    expect_input_error(run_cli("eval", lom_copy.parent, "--scenes", ",", "--checkpoint", random_checkpoint, "--out", out),
                       "--scenes ',': names no scene")
    expect_input_error(run_cli("eval", tmp_path / "nowhere", "--checkpoint", random_checkpoint, "--out", out), "no such folder")
    expect_input_error(run_cli("eval", lom_copy.parent, "--protocol", "novel", "--checkpoint", random_checkpoint, "--out", out),
                  "--protocol 'novel'")
    (tmp_path / "garbage.pth").write_text("garbage")
    for weights in (tmp_path / "missing.pth", tmp_path / "garbage.pth"):  # named as the LPIPS weights, not as a checkpoint
        expect_input_error(run_cli("eval", lom_copy.parent, "--checkpoint", random_checkpoint, "--out", out,
                                   "--lpips-weights", weights), f"--lpips-weights {weights}: ", "give a torchvision vgg16 weight file")
    # under holdout the test frames go through the network but not into the scene: refused before
    # the model loads (named an option eval does not have, --fuse-views, after the network pass)
    result = run_cli("eval", lom_copy.parent, "--protocol", "holdout", "--max-views", 3, "--checkpoint", random_checkpoint,
                     "--out", out, "--geometry", "network")
    expect_input_error(result, "--max-views 3: under the holdout protocol buu's 3 test frame(s)", "raise it above 3")
    assert "fuse" not in result.err
    # under context too, before any scene's work (it was refused by the network pass of this scene,
    # after the scenes before it were evaluated)
    result = run_cli("eval", lom_copy.parent, "--max-views", 2, "--checkpoint", random_checkpoint, "--out", out)
    expect_input_error(result, "--max-views 2: buu's 3 test frames must all go through the network", "at least 3")
    assert "eval (context)" not in result.err
    only_tests = lom_copy.parent.parent / "only-tests" / "buu"  # every frame a test frame
    shutil.copytree(lom_copy, only_tests)
    for photo in [*(only_tests / "low").iterdir(), *(only_tests / "high").iterdir(), *(only_tests / "over_exp").iterdir()]:
        if photo.stem not in ("1", "13", "19"):
            photo.unlink()
    result = run_cli("eval", only_tests.parent, "--protocol", "holdout", "--checkpoint", random_checkpoint, "--out", out)
    expect_input_error(result, "the holdout protocol needs views besides the test frames")
    assert "eval (holdout)" not in result.err  # before the model loads
    shutil.copytree(lom_copy, lom_copy.parent / "mean")  # its rows could not be told from the mean rows
    expect_input_error(run_cli("eval", lom_copy.parent, "--checkpoint", random_checkpoint, "--out", out),
                       "mean: a scene named 'mean' cannot be told from the report's mean rows")
    assert not out.exists()


def test_cameras_are_not_scored_without_reference_poses(run_cli, lom_copy, tmp_path, random_checkpoint):
    (lom_copy / "transforms_train.json").unlink()  # the test frames keep theirs, the other views lose them
    result = run_cli("eval", lom_copy.parent, "--checkpoint", random_checkpoint, "--out", tmp_path / "report",
                     "--max-views", 4, "--geometry", "network", "--refine-steps", 0, "--json")
    assert result.code == 0, result.err
    assert json.loads(result.out)["cameras"] == {}


def test_what_is_in_the_way_is_refused_before_any_scene_is_read(run_cli, lom_copy, tmp_path, random_checkpoint):
    """Without --scenes the contact sheets' names come from the scenes found: a file of the user's
    under one of them is refused before the photos are read (a damaged photo would be named
    otherwise), and a damaged photo in the last scene is named before the first is evaluated."""
    out = tmp_path / "report"
    out.mkdir()
    (out / "contact_sheet_buu.png").write_text("the user's")
    (lom_copy / "low" / "5.JPG").write_bytes(b"not a photo")
    expect_input_error(run_cli("eval", lom_copy.parent, "--checkpoint", random_checkpoint, "--out", out),
                       "contact_sheet_buu.png: exists and was not written by lumos3d")
    (out / "contact_sheet_buu.png").unlink()
    (lom_copy / "low" / "5.JPG").unlink()
    later = lom_copy.parent / "zz"
    shutil.copytree(lom_copy, later)
    (later / "low" / "13.JPG").write_bytes(b"not a photo")
    result = run_cli("eval", lom_copy.parent, "--checkpoint", random_checkpoint, "--out", out, "--geometry", "network",
                     "--max-views", 4, "--refine-steps", 0)
    expect_input_error(result, "zz/low/13.JPG")
    assert "eval (context)" not in result.err  # refused before the evaluation's progress began
    assert sorted(p.name for p in out.iterdir()) == []


def test_eval_inside_a_scene_checks_its_contact_sheet_before_any_work(run_cli, lom_copy, tmp_path, random_checkpoint,
                                                                     monkeypatch):
    """`eval .` named the sheet contact_sheet_.png in the first check, so a file of the user's in
    the way of contact_sheet_buu.png was refused only after the whole evaluation."""
    out = tmp_path / "report"
    out.mkdir()
    (out / "contact_sheet_buu.png").write_text("the user's")
    monkeypatch.chdir(lom_copy)
    result = run_cli("eval", ".", "--checkpoint", random_checkpoint, "--out", out, "--geometry", "network",
                     "--max-views", 4, "--refine-steps", 0)
    expect_input_error(result, "contact_sheet_buu.png: exists and was not written by lumos3d")
    assert "eval (context)" not in result.err
    assert (out / "contact_sheet_buu.png").read_text() == "the user's"


def test_a_frame_listed_as_a_restore_output_is_refused_not_skipped(run_cli, lom_copy, tmp_path, random_checkpoint):
    """A frame photo the folder's manifest names as an earlier restore's output was left out of the
    photos read, and every later frame was scored against the next one's photo (exit 0)."""
    manifest = {"format": "lumos3d-manifest/1",
                "files": {"5.JPG": {"bytes": 1, "sha256": "00", "command": "restore", "output_set": "restore"}}}
    (lom_copy / "low" / ".lumos3d-manifest.json").write_text(json.dumps(manifest))
    result = run_cli("eval", lom_copy.parent, "--checkpoint", random_checkpoint, "--out", tmp_path / "report",
                     "--geometry", "network", "--max-views", 4, "--refine-steps", 0)
    expect_input_error(result, "low/5.JPG: written by an earlier restore", "put the scene's own photo back")
    assert not (tmp_path / "report").exists()


def test_a_model_trained_for_the_other_mode_is_named(run_cli, buu, tmp_path, caplog):
    result = run_cli("eval", buu, "--mode", "over-exposure", "--checkpoint", "low-light", "--out", tmp_path / "report",
                     "--max-views", 4, "--geometry", "network", "--refine-steps", 0, "--baseline", "none")
    assert result.code == 0, result.err
    assert "was trained for low-light photos but the mode is over-exposure" in result.err + caplog.text
    report = json.loads((tmp_path / "report" / "metrics.json").read_text())  # no baseline scored or written
    assert "gamma" not in report["frames"]["buu"] and {row["method"] for row in report["rows"]} == {"lumos3d"}


def test_scores_that_are_not_finite_show_as_n_a_in_the_table():
    from lumos3d_cli.cli.eval import _cell

    assert [_cell(value, 2) for value in (float("inf"), float("nan"), None, 21.456)] == ["n/a", "n/a", "n/a", "21.46"]


def test_scores_that_are_not_finite_are_empty_cells_in_metrics_csv(tmp_path, caplog):
    from lumos3d_cli.pipeline.evaluation import EvalReport, write_eval_report

    rows = [{"scene": "flat", "method": "lumos3d", "psnr": float("inf"), "psnr_gt_mean": float("nan"), "ssim": 1.0,
             "sharpness": float("nan"), "lpips": None, "seconds": 1.0}]
    write_eval_report(EvalReport({"mode": "low-light", "rows": rows}, rows, [], ["lumos3d"]), tmp_path / "report")
    with open(tmp_path / "report" / "metrics.csv") as handle:
        written = next(csv.DictReader(handle))
    assert written["psnr"] == written["psnr_gt_mean"] == written["sharpness"] == "" and written["ssim"] == "1.0"
    assert json.loads((tmp_path / "report" / "metrics.json").read_text())["rows"][0]["psnr"] is None
    assert "metrics.csv: 3 value(s) are not finite, written as empty cells" in caplog.text


def test_the_api_report_is_never_written_into_the_lom_root_it_read(tmp_path):
    """`lumos3d eval lom --out lom` is refused; `write_eval_report(report, "lom")` wrote metrics and
    contact sheets into the data set."""
    from lumos3d_cli.errors import InputError
    from lumos3d_cli.pipeline.evaluation import EvalReport, write_eval_report

    root = tmp_path / "lom"
    (root / "buu").mkdir(parents=True)
    rows = [{"scene": "buu", "method": "lumos3d", "psnr": 20.0, "psnr_gt_mean": 21.0, "ssim": 0.8, "sharpness": 1.0,
             "lpips": None, "seconds": 1.0}]
    report = EvalReport({"mode": "low-light", "root": str(root), "rows": rows}, rows, [], ["lumos3d"])
    for out in (root, root / "buu" / "report"):
        with pytest.raises(InputError, match="input folder"):
            write_eval_report(report, out)
    assert sorted(p.name for p in root.rglob("*")) == ["buu"]
    write_eval_report(report, tmp_path / "report")
