import json
from pathlib import Path

import numpy as np
import pytest
import torch

from lumos3d_cli.data.brackets import VALIDATION_BRACKETS
from lumos3d_cli.errors import InputError
from lumos3d_cli.model.checkpoints import read_checkpoint, save_checkpoint
from lumos3d_cli.model.loading import load_model
from lumos3d_cli.model.lumos3d import build_model
from lumos3d_cli.train.bracket_samples import BracketSamples, validation_indices
from lumos3d_cli.train.config import BracketConfig, load_config
from lumos3d_cli.train.distributed import setup_distributed
from lumos3d_cli.train.selection import SELECTED_FILE, best_earlier_score, drop_stale_selection, is_improvement
from lumos3d_cli.train.trainer import Trainer


def _head_only(tiny_config, brackets, **changes):
    settings = {"optim__steps": 4, "optim__lr": 0.02, "optim__warmup_steps": 0, **changes}
    return tiny_config(stage="student", name="head", model="tiny-operator", multiview=False, validate_every=1,
                       validation_samples=1, brackets={"root": str(brackets), "batch_size": 2, "validation_samples": 3},
                       **settings)


def test_the_selected_weights_are_those_of_the_best_validation(tiny_config, brackets):
    config = _head_only(tiny_config, brackets, select="bracket_psnr")
    trainer = Trainer(load_config(config), setup_distributed("cpu"))
    result = trainer.run()
    run = Path(str(config).replace(".yaml", ""))
    lines = [json.loads(line) for line in (run / "validation.jsonl").read_text().splitlines()]
    assert [line["step"] for line in lines] == [1, 2, 3, 4]
    best = max(lines, key=lambda line: line["bracket_psnr"])
    assert result.selected_checkpoint == run / SELECTED_FILE
    provenance = read_checkpoint(result.selected_checkpoint).provenance
    assert provenance["steps"] == best["step"] and provenance["selected_by"] == "bracket_psnr"
    assert provenance["score"] == pytest.approx(best["bracket_psnr"])
    # scored again from the file, the selected weights give the line they were chosen by
    samples = BracketSamples(load_config(config).brackets, "low-light", (56, 42), (1.0, 1.0), seed=0)
    again = samples.scores(load_model(result.selected_checkpoint), torch.device("cpu"))
    assert again["bracket_psnr"] == pytest.approx(best["bracket_psnr"], abs=1e-4)


def test_the_starting_weights_are_a_candidate_with_validate_at_start(tiny_config, brackets):
    # lr 0: no step changes the weights (nor does weight decay), so no later validation beats step 0
    config = _head_only(tiny_config, brackets, select="bracket_psnr", validate_at_start=True, optim__lr=0.0)
    trainer = Trainer(load_config(config), setup_distributed("cpu"))
    start = {name: value.clone() for name, value in trainer.model.state_dict().items()}
    result = trainer.run()
    run = Path(str(config).replace(".yaml", ""))
    lines = [json.loads(line) for line in (run / "validation.jsonl").read_text().splitlines()]
    assert [line["step"] for line in lines] == [0, 1, 2, 3, 4]
    assert len({line["bracket_psnr"] for line in lines}) == 1
    selected = read_checkpoint(result.selected_checkpoint)
    assert selected.provenance["steps"] == 0
    assert all(torch.equal(selected.tensors[name], value) for name, value in start.items())


def test_selection_is_checked_in_the_config(tiny_config, brackets):
    with pytest.raises(InputError, match="select: 'loss' is not a validation score"):
        load_config(_head_only(tiny_config, brackets, select="loss"))
    with pytest.raises(InputError, match="set validate_every"):
        load_config(tiny_config(select="psnr"))
    with pytest.raises(InputError, match="scores the held-out brackets: set brackets.root"):
        load_config(tiny_config(select="bracket_psnr", validate_every=2))
    with pytest.raises(InputError, match="validate_at_start .* set validate_every"):
        load_config(tiny_config(validate_at_start=True))


def test_best_earlier_score_and_improvement(tmp_path):
    log = tmp_path / "validation.jsonl"
    assert best_earlier_score(log, "psnr", 10) is None
    log.write_text("".join(json.dumps({"step": s, "psnr": p}) + "\n" for s, p in [(2, 20.0), (4, 23.0), (6, 21.0)]))
    assert best_earlier_score(log, "psnr", 4) == 20.0 and best_earlier_score(log, "psnr", 7) == 23.0
    assert best_earlier_score(log, "bracket_psnr", 7) is None
    assert is_improvement(23.5, 23.0) and not is_improvement(23.0, 23.0) and is_improvement(-5.0, None)
    assert not is_improvement(float("nan"), None) and not is_improvement(float("inf"), 1.0)


def test_a_stale_selection_is_removed(tmp_path):
    model = build_model("tiny-operator", seed=0)
    path = tmp_path / SELECTED_FILE
    save_checkpoint(model, path, {"steps": 4})
    drop_stale_selection(tmp_path, start=4)  # resumed at the step it was chosen: kept
    assert path.is_file()
    drop_stale_selection(tmp_path, start=2)  # chosen in work a resume at step 2 redoes: dropped
    assert not path.exists()
    save_checkpoint(model, path, {"steps": 2})
    drop_stale_selection(tmp_path, start=0)  # a fresh run inherits no selection
    assert not path.exists()
    drop_stale_selection(tmp_path, start=0)  # nothing to remove: no error


def test_validation_covers_every_held_out_bracket(brackets):
    assert list(validation_indices(5, None)) == [0, 1, 2, 3, 4] and list(validation_indices(5, 9)) == [0, 1, 2, 3, 4]
    spaced = validation_indices(51, 20)
    assert len(spaced) == 20 and spaced[0] == 0 and spaced[-1] == 50 and np.all(np.diff(spaced) >= 2)
    samples = BracketSamples(BracketConfig(root=str(brackets)), "low-light", (56, 42), (1.0, 1.0), seed=0)
    pairs = samples.validation[0].pairs
    assert {Path(p.input_path).parent.name for p in pairs} == set(VALIDATION_BRACKETS)
    scores = samples.scores(build_model("tiny-operator", seed=0), torch.device("cpu"))
    assert scores["bracket_samples"] == len(pairs)  # every held-out pair by default
    assert scores["bracket_well_exposed_samples"] == len(samples.validation_well_exposed[0].pairs)
    few = BracketSamples(BracketConfig(root=str(brackets), validation_samples=20), "low-light", (56, 42), (1.0, 1.0), seed=0)
    chosen = [pairs[i] for i in validation_indices(len(pairs), 20)]
    assert len({Path(p.input_path).parent.name for p in chosen}) >= 15  # the first 20 pairs held 8 brackets
    assert few.scores(build_model("tiny-operator", seed=0), torch.device("cpu"))["bracket_samples"] == 20
