"""Strict JSON out: non-finite values become null and are said (io/json_text.py), read back by
the standard library's parser told to refuse NaN and Infinity."""

import json
import logging

import pytest

from lumos3d_cli.io.json_text import finite_document, json_text


def _strict(text: str):
    def refuse(constant):
        raise ValueError(f"not JSON: {constant}")

    return json.loads(text, parse_constant=refuse)


def test_non_finite_values_are_null_and_named(caplog):
    document = {"psnr": float("inf"), "views": [{"ssim": 0.5, "sharpness": float("nan")}], "n": 3, "name": "a"}
    with caplog.at_level(logging.WARNING):
        text = json_text(document, "summary.json")
    assert _strict(text) == {"psnr": None, "views": [{"ssim": 0.5, "sharpness": None}], "n": 3, "name": "a"}
    assert "summary.json: 2 value(s) are not finite, written as null: psnr (inf), views[0].sharpness (nan)" in caplog.text
    with pytest.raises(ValueError, match="not JSON: Infinity"):
        _strict(json.dumps(document))  # what the standard writer would have written


def test_a_finite_document_passes_unchanged_and_silent(caplog):
    document = {"a": [1.5, -2.0, {"b": None}], "c": True}
    with caplog.at_level(logging.WARNING):
        assert finite_document(document, "x.json") == document
        assert _strict(json_text(document)) == document
    assert caplog.text == ""


def test_numpy_numbers_are_numbers():
    import numpy as np

    text = json_text({"a": np.float32(0.5), "b": np.int64(3), "c": np.float64("nan"), "d": np.bool_(True)})
    assert _strict(text) == {"a": 0.5, "b": 3, "c": None, "d": True}
