import re
from pathlib import Path

import pytest

from lumos3d_cli.errors import InputError
from lumos3d_cli.train.config import config_to_yaml, load_config
from lumos3d_cli.train.schedule import learning_rate_factor

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.yaml")), ids=lambda p: p.name)
def test_every_example_config_is_valid(path):
    config = load_config(path)
    assert load_config(path) == config
    assert config.optim.lr > 0 and config.data.width % 14 == 0 and config.data.height % 14 == 0


def test_the_gpu_recipe_matches_the_paper():
    config = load_config(CONFIGS / "vggt-1b-gpu.yaml")
    assert config.optim.lr == 2e-4 and config.optim.warmup_steps == 1000 and config.optim.steps == 30000
    assert config.data.views == 22 and config.precision == "bf16" and config.stage == "student"
    assert (config.loss.content, config.loss.image, config.loss.voxel) == (0.1, 1.0, 0.01)


def test_overrides_and_errors(tmp_path):
    config = load_config(CONFIGS / "low-light.yaml", ["optim.lr=1e-4", "data.views=6", "degrade.noise=true"])
    assert config.optim.lr == 1e-4 and config.data.views == 6 and config.degrade.noise
    with pytest.raises(InputError, match="unknown config key .optim.warmup. \\(did you mean .optim.warmup_steps.\\?\\)"):
        load_config(CONFIGS / "low-light.yaml", ["optim.warmup=1"])
    with pytest.raises(InputError, match="config key 'data.views': expected an integer, got 'many'"):
        load_config(CONFIGS / "low-light.yaml", ["data.views=many"])
    (tmp_path / "student.yaml").write_text("stage: student\noutput: x\n")
    with pytest.raises(InputError, match="stage 'student' needs `teacher`"):
        load_config(tmp_path / "student.yaml")
    for override, message in (("data.width=0", "data.width x data.height = 0x168"), ("log_every=0", "log_every: 0"),
                              ("validate_every=-1", "validate_every: -1"), ("max_nonfinite_steps=0", "max_nonfinite_steps: 0"),
                              ("checkpoint_every=-5", "checkpoint_every: -5"), ("seed=-1", "seed: -1 must be"),
                              ("seed=99999999999999999999999", "seed: 99999999999999999999999 must be"),
                              ("data.samples_per_scene=0", "data.samples_per_scene=0 must be at least 1"),
                              ("loss.lumos=-1", "loss.lumos: -1.0 must be a weight of at least 0"),
                              ("loss.reconstruction=.nan", "loss.reconstruction: nan must be"),
                              ("degrade.white_balance=[1.2,0.8]", r"white_balance=\(1.2, 0.8\) must satisfy"),
                              ("loss.background=[.nan,0,0]", r"config loss.background.0: not a finite number"),
                              ("degrade.colour_cast=[.inf,.inf]", "degrade.colour_cast.0, degrade.colour_cast.1: not a finite"),
                              ("brackets.weight=nan", "brackets.weight: not a finite number")):
        with pytest.raises(InputError, match=message):  # once an internal error or silently accepted
            load_config(CONFIGS / "low-light.yaml", [override])
    (tmp_path / "twice.yaml").write_text("stage: teacher\noutput: x\noptim: {steps: 6}\noptim: {lr: 1.0}\n")
    with pytest.raises(InputError, match=r"twice.yaml: invalid YAML at line 4, column 1 \(key 'optim' given twice"):
        load_config(tmp_path / "twice.yaml")  # the second block replaced the first: 6 steps became 30,000
    (tmp_path / "listkey.yaml").write_text("stage: teacher\noutput: x\n? [a, b]\n: 1\n")
    with pytest.raises(InputError, match=r"listkey.yaml: invalid YAML at line 3, column 3 \(a key \['a', 'b'\] that is not a name"):
        load_config(tmp_path / "listkey.yaml")  # an internal TypeError (unhashable) before
    (tmp_path / "bad.yaml").write_text("stage: [unclosed")
    with pytest.raises(InputError, match=r"bad.yaml: invalid YAML at line 1, column 17 \(.*\); correct the file") as error:
        load_config(tmp_path / "bad.yaml")
    assert "\n" not in str(error.value)
    with pytest.raises(InputError, match=r"override value '\[1': invalid YAML at line 1, column 3 .*; quote it") as error:
        load_config(CONFIGS / "low-light.yaml", ["optim.lr=[1"])
    assert "\n" not in str(error.value)


def test_mixed_mode_takes_per_mode_ranges():
    config = load_config(CONFIGS / "ablation-mixed.yaml")
    assert config.degrade.ranges("low-light").exposure == (0.03, 0.2)
    assert config.degrade.ranges("over-exposure").gamma == (1.2, 2.2)
    single = load_config(CONFIGS / "default-low-light.yaml")
    assert single.degrade.ranges("low-light").exposure == (0.03, 0.2)
    with pytest.raises(InputError, match="degrade.mode=mixed takes its ranges from degrade.low_light"):
        load_config(CONFIGS / "default-low-light.yaml", ["degrade.mode=mixed"])
    with pytest.raises(InputError, match="teacher_input"):
        load_config(CONFIGS / "default-low-light.yaml", ["teacher_input=low-light"])


def test_resolved_config_round_trips(tmp_path):
    config = load_config(CONFIGS / "over-exposure.yaml")
    (tmp_path / "resolved.yaml").write_text(config_to_yaml(config))
    assert load_config(tmp_path / "resolved.yaml") == config


def test_warmup_then_cosine():
    factors = [learning_rate_factor(s, 10, 110, 0.1) for s in range(110)]
    assert factors[0] == pytest.approx(0.1) and factors[9] == pytest.approx(1.0)
    assert factors[10] == pytest.approx(1.0) and factors[60] == pytest.approx(0.55)
    assert factors[-1] == pytest.approx(0.1, abs=1e-3)
    assert all(a >= b for a, b in zip(factors[10:], factors[11:]))


def test_settings_a_short_run_never_reaches_are_warned_of(tiny_config, caplog):
    """A 4-step test of a config warming up over 100 steps peaked at 4 % of optim.lr; a selection
    with validate_every beyond the run selected nothing; neither was said."""
    import logging

    from lumos3d_cli.train.config import warn_of_idle_settings

    config = load_config(tiny_config(name="short"), ["optim.steps=4", "optim.warmup_steps=100", "validate_every=10",
                                                     "select=psnr"])
    with caplog.at_level(logging.WARNING, logger="lumos3d_cli.train.config"):
        warn_of_idle_settings(config)
    assert "optim.warmup_steps 100 is more than optim.steps 4: the learning rate never reaches optim.lr" in caplog.text
    assert "select: psnr, but validate_every 10 is more than optim.steps 4: no validation runs" in caplog.text


def test_a_config_that_is_not_utf8_text_is_named(tmp_path):
    """A binary file ended in an internal UnicodeDecodeError."""
    (tmp_path / "bin.yaml").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(InputError, match=r"bin.yaml: not a UTF-8 text file \(byte 0xff at offset 0\); give a YAML config"):
        load_config(tmp_path / "bin.yaml")


def test_an_empty_config_is_named(tmp_path):
    (tmp_path / "empty.yaml").write_text("")
    with pytest.raises(InputError, match=r"^\S*empty.yaml: config is missing required key\(s\): stage, output$"):
        load_config(tmp_path / "empty.yaml")
    with pytest.raises(InputError, match=r"^\S*empty.yaml with its overrides: config is missing required key\(s\): output$"):
        load_config(tmp_path / "empty.yaml", ["stage=teacher"])


def test_yaml_merge_keys_work_and_explicit_keys_stay_unique(tmp_path):
    """`<<: *base` was refused ("could not determine a constructor for the tag ...merge"), where
    yaml.safe_load takes it."""
    (tmp_path / "merge.yaml").write_text("stage: teacher\noutput: x\ndegrade:\n  mode: mixed\n"
                                         "  low_light: &ranges {exposure: [0.05, 0.1], gamma: [1.5, 2.0]}\n"
                                         "  over_exposure: {<<: *ranges, exposure: [2.0, 3.0]}\n")
    ranges = load_config(tmp_path / "merge.yaml").degrade.over_exposure
    assert (ranges.exposure, ranges.gamma) == ((2.0, 3.0), (1.5, 2.0))  # the explicit key wins over the merged one
    (tmp_path / "twice.yaml").write_text("stage: teacher\noutput: x\ndata: {<<: {views: 6}, width: 56, width: 112}\n")
    with pytest.raises(InputError, match=r"twice.yaml: invalid YAML at line 3, column \d+ \(key 'width' given twice"):
        load_config(tmp_path / "twice.yaml")
    # a mapping merged into one that is itself merged: its own keys beside its merge are no repeats
    (tmp_path / "nested.yaml").write_text("stage: teacher\noutput: x\nbase: &base {lr: 0.001, steps: 10}\n"
                                          "defaults: {optim: &o {<<: *base, lr: 0.002}}\noptim: {<<: *o}\n")
    with pytest.raises(InputError, match="unknown config key 'base'"):  # parsed: the schema has no such key
        load_config(tmp_path / "nested.yaml")
    with pytest.raises(InputError, match=r"override value .*invalid YAML.*key 'lr' given twice"):
        load_config(tmp_path / "merge.yaml", ["optim={lr: 1, lr: 2}"])


def test_a_mapping_override_merges_into_its_section_and_a_key_is_given_once(tmp_path):
    """`optim.steps=3 'optim={lr: 0.001}'` trained 30,000 steps: the mapping replaced the section,
    every other key back to its default; `optim.lr=1 optim.lr=2` took the last silently."""
    (tmp_path / "run.yaml").write_text("stage: teacher\noutput: x\noptim: {steps: 6, warmup_steps: 2}\n")
    config = load_config(tmp_path / "run.yaml", ["optim.steps=3", "optim={lr: 0.001}"])
    assert (config.optim.steps, config.optim.warmup_steps, config.optim.lr) == (3, 2, 0.001)
    for overrides, message in ((["optim.lr=1", "optim.lr=2"], "override 'optim.lr=2': optim.lr is also set by 'optim.lr=1'"),
                               (["optim.lr=1", "optim={lr: 2}"], "optim.lr is also set by 'optim.lr=1'"),
                               (["optim.lr=1", "optim=3"], "override 'optim=3': optim is also set by 'optim.lr=1'")):
        with pytest.raises(InputError, match=re.escape(message) + "; give each key once"):
            load_config(tmp_path / "run.yaml", overrides)
