import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.train.config import load_config
from lumos3d_cli.train.distributed import setup_distributed
from lumos3d_cli.train.trainer import Trainer


def _trainer(path):
    return Trainer(load_config(path), setup_distributed("cpu"))


def test_a_head_only_step_moves_the_head_and_nothing_else(tiny_config, brackets):
    config = tiny_config(stage="student", name="head", appearance="operator", trainable=["illumination_head"],
                         multiview=False, optim__warmup_steps=0, brackets={"root": str(brackets), "batch_size": 2})
    trainer = _trainer(config)
    assert trainer.teacher is None
    before = {name: value.clone() for name, value in trainer.model.state_dict().items()}
    report = trainer.step(0)
    assert not report.skipped and set(report.terms) == {"brackets", "total"}
    assert report.terms["total"] == report.terms["brackets"] > 0
    after = trainer.model.state_dict()
    moved = {name for name in before if not torch.equal(before[name], after[name])}
    assert moved and all(name.startswith("illumination_head.") for name in moved)
    assert "illumination_head.scene_out.weight" in moved  # zero at init: identity operator
    frozen = [p for n, p in trainer.model.named_parameters() if not n.startswith("illumination_head.")]
    assert frozen and all(not p.requires_grad and p.grad is None for p in frozen)


def test_trainable_names_modules_of_the_model(tiny_config):
    # the regression model has no illumination head to train
    with pytest.raises(InputError, match="illumination_head is not a module"):
        _trainer(tiny_config(trainable=["illumination_head"]))


def test_dropping_the_multiview_objective_needs_brackets(tiny_config):
    with pytest.raises(InputError, match="brackets.root"):
        load_config(tiny_config(stage="student", multiview=False))


def test_the_appearance_loss_of_multiview_samples_trains_the_head_without_a_teacher(tiny_config):
    config = tiny_config(stage="student", name="head-mv", appearance="operator", trainable=["illumination_head"],
                         multiview_loss="appearance", optim__warmup_steps=0)
    trainer = _trainer(config)
    assert trainer.teacher is None
    before = {name: value.clone() for name, value in trainer.model.state_dict().items()}
    report = trainer.step(0)
    assert not report.skipped and set(report.terms) == {"appearance", "total"} and report.terms["appearance"] > 0
    moved = {name for name in before if not torch.equal(before[name], trainer.model.state_dict()[name])}
    assert moved and all(name.startswith("illumination_head.") for name in moved)


def test_the_appearance_loss_of_multiview_samples_needs_an_operator(tiny_config):
    with pytest.raises(InputError, match="appearance: operator"):
        _trainer(tiny_config(stage="student", name="reg-mv", multiview_loss="appearance"))
