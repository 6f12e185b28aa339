from dataclasses import dataclass, field
from typing import Literal

import pytest
import yaml

from lumos3d_cli.errors import InputError
from lumos3d_cli.typed_config import apply_override, apply_overrides, from_dict, to_dict


@dataclass
class Inner:
    rate: float = 1.0
    steps: int = 10
    ranges: tuple[float, float] = (0.1, 0.2)


@dataclass
class Outer:
    name: str
    mode: Literal["a", "b"] = "a"
    path: str | None = None
    tags: list[str] = field(default_factory=list)
    inner: Inner = field(default_factory=Inner)
    flag: bool = False


def test_builds_nested_typed_values():
    config = from_dict(Outer, {"name": "x", "mode": "b", "tags": ["p"], "inner": {"rate": 2, "ranges": [0.5, 0.6]}})
    assert config.inner.rate == 2.0 and isinstance(config.inner.rate, float)
    assert config.inner.ranges == (0.5, 0.6) and config.tags == ["p"] and config.path is None
    assert from_dict(Outer, to_dict(config)) == config


@pytest.mark.parametrize(
    "values, message",
    [
        ({"name": "x", "inner": {"rat": 1}}, "unknown config key 'inner.rat' (did you mean 'inner.rate'?)"),
        ({"name": "x", "colour": 1}, "unknown config key 'colour'; known keys: name, mode"),
        ({"name": "x", "inner": {"steps": 1.5}}, "config key 'inner.steps': expected an integer, got 1.5"),
        ({"name": "x", "mode": "c"}, "config key 'mode': expected 'a' or 'b', got 'c'"),
        ({"name": "x", "flag": "yes"}, "config key 'flag': expected true/false, got 'yes'"),
        ({"name": "x", "inner": {"ranges": [1]}}, "config key 'inner.ranges': expected 2 values"),
        ({"name": "x", "inner": 3}, "config key 'inner': expected a mapping"),
        ({}, "missing required key(s): name"),
    ],
)
def test_errors_name_the_key(values, message):
    with pytest.raises(InputError) as error:
        from_dict(Outer, values)
    assert message in str(error.value)


def test_overrides():
    values = {"name": "x", "inner": {"rate": 1.0}}
    apply_override(values, "inner.rate=3e-4", yaml.safe_load)
    apply_override(values, "tags=[a, b]", yaml.safe_load)
    apply_override(values, "inner.steps=7", yaml.safe_load)
    config = from_dict(Outer, values)
    assert config.inner.rate == 3e-4 and config.tags == ["a", "b"] and config.inner.steps == 7
    with pytest.raises(InputError, match="write it as key=value"):
        apply_override(values, "inner.rate", yaml.safe_load)
    with pytest.raises(InputError, match="'name' is not a section"):
        apply_override(values, "name.first=1", yaml.safe_load)


def test_a_mapping_override_merges_and_a_key_is_set_once():
    values = {"name": "x", "inner": {"rate": 1.0, "steps": 3}}
    apply_overrides(values, ["inner={rate: 2.0}", "tags=[a]"], yaml.safe_load)
    assert from_dict(Outer, values).inner == Inner(rate=2.0, steps=3)  # steps kept, not back to its default 10
    with pytest.raises(InputError, match=r"override 'inner.steps=5': inner.steps is also set by 'inner=\{steps: 4\}'"):
        apply_overrides(values, ["inner={steps: 4}", "inner.steps=5"], yaml.safe_load)
    apply_overrides(values, ["inner.rate=3", "inner.steps=5"], yaml.safe_load)  # two keys of one section
    assert from_dict(Outer, values).inner == Inner(rate=3.0, steps=5)
