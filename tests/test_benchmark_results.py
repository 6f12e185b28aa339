"""benchmarks/report.py's check of a `--json` results path, made before a benchmark runs: a
folder or a missing folder lost minutes of measuring at the end, and a photo given by mistake
was replaced by the results."""

import importlib.util
import json
from pathlib import Path

import pytest

REPORT = Path(__file__).resolve().parents[1] / "benchmarks" / "report.py"


@pytest.fixture(scope="module")
def report():
    spec = importlib.util.spec_from_file_location("benchmark_report", REPORT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_results_path_is_checked_before_the_run(report, tmp_path):
    (tmp_path / "photo.jpg").write_bytes(b"\xff\xd8\xff\xe0 a photo")
    (tmp_path / "notes.json").write_text("my notes, not JSON")
    (tmp_path / "earlier.json").write_text(json.dumps({"rows": []}))
    assert report.check_result_file(None) is None
    assert report.check_result_file(tmp_path / "new.json") is None
    assert report.check_result_file(tmp_path / "earlier.json") is None  # an earlier run's results: replaced
    assert "is a folder" in report.check_result_file(tmp_path)
    assert "give a .json file" in report.check_result_file(tmp_path / "photo.jpg")
    assert "is not a JSON document" in report.check_result_file(tmp_path / "notes.json")
    assert (tmp_path / "photo.jpg").read_bytes() == b"\xff\xd8\xff\xe0 a photo"
