import json
from pathlib import Path

import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.model.lumos3d import build_model
from lumos3d_cli.train.bracket_samples import BracketSamples
from lumos3d_cli.train.config import BracketConfig, load_config
from lumos3d_cli.train.distributed import setup_distributed
from lumos3d_cli.train.trainer import Trainer


def _trainer(path, overrides=()):
    return Trainer(load_config(path, list(overrides)), setup_distributed("cpu"))


def test_operator_student_trains_on_brackets_and_validates_on_the_held_out_ones(tiny_config, brackets):
    teacher = _trainer(tiny_config(name="teacher", optim__steps=1)).run()
    config = tiny_config(stage="student", name="student", model=str(teacher.final_checkpoint), appearance="operator",
                         teacher=str(teacher.final_checkpoint), optim__steps=2, validate_every=2, validation_samples=1,
                         brackets={"root": str(brackets), "batch_size": 2, "validation_samples": 2})
    trainer = _trainer(config)
    assert trainer.model.architecture.appearance == "operator"
    result = trainer.run()
    terms = result.history[-1].terms
    assert {"brackets", "image", "total"} <= set(terms) and 0 < terms["brackets"] < 1
    head = trainer.model.illumination_head.scene_out
    assert float(head.weight.detach().abs().sum()) > 0  # the zero-initialised output layer moved
    run = Path(str(config).replace(".yaml", ""))
    line = json.loads((run / "validation.jsonl").read_text().splitlines()[-1])
    assert line["bracket_samples"] == 2 and 5 < line["bracket_psnr"] < 60 and 0 < line["bracket_ssim"] <= 1
    # the well-exposed inputs (a frame beside or equal to the target) are scored apart: barely
    # touched by a head this young, so far closer to their targets than the dark ones
    assert line["bracket_psnr"] + 5 < line["bracket_well_exposed_psnr"] <= 100 and 0 < line["bracket_well_exposed_ssim"] <= 1


def test_well_exposed_inputs_join_training_only_when_asked(brackets):
    size, crop = (56, 42), (1.0, 1.0)
    standard = BracketSamples(BracketConfig(root=str(brackets)), "low-light", size, crop, seed=0)
    widened = BracketSamples(BracketConfig(root=str(brackets), well_exposed=True), "low-light", size, crop, seed=0)
    standard_pairs, widened_pairs = standard.train[0].pairs, widened.train[0].pairs
    assert set(standard_pairs) < set(widened_pairs)
    assert all(p.input_mean <= p.target_mean / 2 for p in standard_pairs)
    extra = set(widened_pairs) - set(standard_pairs)
    assert all(p.target_mean / 2 < p.input_mean <= p.target_mean for p in extra)
    assert any(p.input_path == p.target_path for p in extra)  # the target as its own input
    # validation is the same in both: the restoration pairs, and the well-exposed ones apart
    assert standard.validation[0].pairs == widened.validation[0].pairs
    assert all(p.input_mean > p.target_mean / 2 for p in standard.validation_well_exposed[0].pairs)


def test_brackets_need_an_operator_model(tiny_config, brackets):
    config = tiny_config(optim__steps=1, brackets={"root": str(brackets)})
    with pytest.raises(InputError, match="operator"):
        _trainer(config)


def test_batches_are_deterministic_and_mixed_mode_alternates(brackets):
    samples = BracketSamples(BracketConfig(root=str(brackets), batch_size=2), "mixed", (56, 42), (0.6, 1.0), seed=0)
    first, _ = samples._batch(samples.train, [0, 1])
    again, _ = samples._batch(samples.train, [0, 1])
    torch.testing.assert_close(first, again)
    assert first.shape == (2, 1, 3, 42, 56)
    assert float(first[0].mean()) < float(first[1].mean())  # low-light pair, then over-exposure pair
    model = build_model("tiny-operator", seed=0)
    loss = samples.loss(model, step=3, rank=0, world_size=1, device=torch.device("cpu"))
    loss.backward()
    assert bool(torch.isfinite(loss)) and model.illumination_head.scene_out.weight.grad is not None


def test_held_out_crops_do_not_depend_on_the_run_seed(brackets):
    # SICE frames are square: the network's 4:3 crop has a free vertical position
    size = (56, 42)
    first, second = (BracketSamples(BracketConfig(root=str(brackets)), "low-light", size, (0.6, 1.0), seed=s) for s in (0, 1))
    for one, other in ((first.validation[0], second.validation[0]), (first.validation_well_exposed[0], second.validation_well_exposed[0])):
        for index in (0, len(one) // 2, len(one) - 1):
            assert torch.equal(one[index]["images"], other[index]["images"])
            assert torch.equal(one[index]["targets"], other[index]["targets"])
    # training crops do follow the seed
    assert not torch.equal(first.train[0][0]["images"], second.train[0][0]["images"])


def test_an_unknown_model_in_the_config_is_named_as_the_configs_key(tiny_config):
    """`model: huge` is the config's, not a --checkpoint the user never passed."""
    with pytest.raises(InputError, match=r"^the config's model huge: no such file or folder.*nor an architecture \(tiny") as caught:
        _trainer(tiny_config(optim__steps=1, model="huge"))
    assert caught.value.parameter is None
