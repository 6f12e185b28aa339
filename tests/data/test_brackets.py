import json

import numpy as np
import pytest
import torch
from PIL import Image

from lumos3d_cli.data.brackets import (
    VALIDATION_BRACKETS, BracketDataset, bracket_pairs, pair_frames, read_bracket_index,
)
from lumos3d_cli.errors import InputError


def test_pairing_rule():
    frames = [("00.jpg", 0.05), ("01.jpg", 0.2), ("02.jpg", 0.3), ("03.jpg", 0.46), ("04.jpg", 0.7), ("05.jpg", 0.75), ("06.jpg", 0.95)]
    # target 03 (closest to 0.45); low-light: mean <= 0.23; over-exposure: 1 - mean <= 0.27.
    assert pair_frames(frames, "low-light") == [(0, 3), (1, 3)]
    assert pair_frames(frames, "over-exposure") == [(5, 3), (6, 3)]
    # Well-exposed pairs add the frames between the inputs and the target, and the target itself
    # (as its own target), and nothing of the other side of the target.
    assert pair_frames(frames, "low-light", inputs="both") == [(0, 3), (1, 3), (2, 3), (3, 3)]
    assert pair_frames(frames, "over-exposure", inputs="well-exposed") == [(3, 3), (4, 3)]
    # No frame near a good exposure: no pairs at all.
    assert pair_frames([("00.jpg", 0.02), ("01.jpg", 0.1)], "low-light") == []
    with pytest.raises(InputError, match="unknown mode"):
        pair_frames(frames, "dusk")
    with pytest.raises(InputError, match="unknown bracket inputs"):
        pair_frames(frames, "low-light", inputs="all")


def test_missing_or_malformed_index_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="brackets.json"):
        read_bracket_index(tmp_path)
    (tmp_path / "brackets.json").write_text('{"000": [{"name": "x"}]}')
    with pytest.raises(InputError, match="brackets.json"):
        read_bracket_index(tmp_path)


def test_missing_frame_file_is_named(tmp_path):
    (tmp_path / "001").mkdir()
    Image.fromarray(np.full((32, 32, 3), 110, np.uint8)).save(tmp_path / "001" / "01.jpg")
    index = {"001": [{"file": "00.jpg", "mean": 0.05}, {"file": "01.jpg", "mean": 0.44}]}
    (tmp_path / "brackets.json").write_text(json.dumps(index))
    dataset = BracketDataset(tmp_path, "low-light", "train", (16, 16))
    with pytest.raises(InputError, match="00.jpg"):
        dataset[0]


def test_validation_split_is_fixed_disjoint_and_covers_both_modes(brackets):
    assert len(VALIDATION_BRACKETS) == 20
    for mode in ("low-light", "over-exposure"):
        validation = bracket_pairs(brackets, mode, "validation")
        train = bracket_pairs(brackets, mode, "train")
        assert {p.bracket for p in validation} == set(VALIDATION_BRACKETS)
        assert not {p.bracket for p in train} & set(VALIDATION_BRACKETS)
        assert len(bracket_pairs(brackets, mode, "all")) == len(train) + len(validation)
    low = bracket_pairs(brackets, "low-light", "all")
    assert all(p.input_mean <= p.target_mean / 2 for p in low)
    assert len(low) > 400


def test_samples_are_aligned_crops_of_the_real_frames(brackets):
    dataset = BracketDataset(brackets, "low-light", "validation", (224, 168), seed=1)
    sample = dataset[0]
    assert sample["images"].shape == sample["targets"].shape == (1, 3, 168, 224)
    assert sample["bracket"] in VALIDATION_BRACKETS and sample["mode"] == "low-light"
    assert float(sample["images"].mean()) < float(sample["targets"].mean())
    torch.testing.assert_close(dataset[0]["images"], sample["images"])  # deterministic
    # Aligned: the darker frame's structure correlates with the target's.
    a = sample["images"].flatten() - sample["images"].mean()
    b = sample["targets"].flatten() - sample["targets"].mean()
    assert float((a * b).sum() / (a.norm() * b.norm())) > 0.5


def test_whole_frame_for_validation(brackets):
    dataset = BracketDataset(brackets, "over-exposure", "validation", (256, 256), crop_scale=(1.0, 1.0), flip=False)
    pair = dataset.pairs[0]
    sample = dataset[0]
    target = torch.from_numpy(np.asarray(Image.open(pair.target_path).convert("RGB"), dtype=np.float32) / 255).permute(2, 0, 1)
    expected = torch.nn.functional.interpolate(target[None], size=(256, 256), mode="bilinear", antialias=True)
    torch.testing.assert_close(sample["targets"], expected.clamp(0, 1), atol=0.02, rtol=0)
    assert float(sample["images"].mean()) > float(sample["targets"].mean())
