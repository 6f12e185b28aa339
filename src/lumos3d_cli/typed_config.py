"""Build typed dataclasses from plain dicts (parsed YAML or JSON), strictly: unknown keys and
values of the wrong type are errors that name the key. The one config mechanism of the project:
the training config, the degradation settings and the model architecture (as stored in
checkpoints) are all built with `from_dict` and written with `to_dict`."""

from __future__ import annotations

import dataclasses
import difflib
import types
import typing
from typing import Any, Literal, TypeVar, Union

from lumos3d_cli.errors import InputError

T = TypeVar("T")


def _type_name(annotation) -> str:
    origin = typing.get_origin(annotation)
    if origin is Literal:
        return " or ".join(repr(v) for v in typing.get_args(annotation))
    if origin in (Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(annotation))
    if origin in (list, tuple):
        return f"a list of {_type_name(typing.get_args(annotation)[0])}"
    if dataclasses.is_dataclass(annotation):
        return "a mapping"
    return {bool: "true/false", int: "an integer", float: "a number", str: "a string", type(None): "null"}.get(
        annotation, getattr(annotation, "__name__", str(annotation))
    )


def _convert(value: Any, annotation, key: str) -> Any:
    origin = typing.get_origin(annotation)
    arguments = typing.get_args(annotation)
    if dataclasses.is_dataclass(annotation):
        if not isinstance(value, dict):
            raise InputError(f"config key '{key}': expected a mapping, got {value!r}")
        return from_dict(annotation, value, key)
    if origin in (Union, types.UnionType):
        if value is None and type(None) in arguments:
            return None
        for option in arguments:
            if option is type(None):
                continue
            try:
                return _convert(value, option, key)
            except InputError:
                continue
        raise InputError(f"config key '{key}': expected {_type_name(annotation)}, got {value!r}")
    if origin is Literal:
        if value not in arguments:
            raise InputError(f"config key '{key}': expected {_type_name(annotation)}, got {value!r}")
        return value
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise InputError(f"config key '{key}': expected {_type_name(annotation)}, got {value!r}")
        if origin is tuple and arguments and arguments[-1] is not Ellipsis:
            if len(value) != len(arguments):
                raise InputError(f"config key '{key}': expected {len(arguments)} values, got {list(value)!r}")
            return tuple(_convert(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, arguments)))
        item = arguments[0] if arguments else Any
        converted = [_convert(v, item, f"{key}[{i}]") for i, v in enumerate(value)]
        return tuple(converted) if origin is tuple else converted
    if annotation is Any:
        return value
    if annotation is bool:
        if isinstance(value, bool):
            return value
    elif annotation is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif annotation is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        if isinstance(value, str):  # YAML 1.1 reads 1e-4 (no dot) as a string
            try:
                return float(value)
            except ValueError:
                pass
    elif annotation is str:
        if isinstance(value, str):
            return value
    raise InputError(f"config key '{key}': expected {_type_name(annotation)}, got {value!r}")


def from_dict(cls: type[T], values: dict, prefix: str = "") -> T:
    """cls(**values) with every value converted to its field type; errors name the full key."""
    if not isinstance(values, dict):
        where = f"config key '{prefix}'" if prefix else "config"
        raise InputError(f"{where}: expected a mapping, got {values!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = [name for name in values if name not in fields]
    if unknown:
        name = unknown[0]
        close = difflib.get_close_matches(str(name), list(fields), n=1)
        hint = f" (did you mean '{_join(prefix, close[0])}'?)" if close else f"; known keys: {', '.join(fields)}"
        raise InputError(f"unknown config key '{_join(prefix, name)}'{hint}")
    converted = {name: _convert(value, hints[name], _join(prefix, name)) for name, value in values.items()}
    missing = [
        name for name, f in fields.items()
        if name not in converted and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise InputError(f"config is missing required key(s): {', '.join(_join(prefix, m) for m in missing)}")
    try:
        return cls(**converted)
    except (ValueError, TypeError) as error:
        raise InputError(f"config {prefix or 'root'}: {error}") from error


def to_dict(instance) -> dict:
    """Plain dict (lists for tuples) of a config dataclass, for YAML."""

    def plain(value):
        if dataclasses.is_dataclass(value):
            return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
        if isinstance(value, (list, tuple)):
            return [plain(v) for v in value]
        return value

    return plain(instance)


def apply_override(values: dict, assignment: str, parse) -> list[tuple[str, ...]]:
    """Set `a.b.c=value` in a nested dict; `parse` turns the text into a value (YAML rules). A
    mapping given for a section is merged into it key by key (replacing the section put every key
    the value left out back to its default: `optim={lr: 1e-3}` undid optim.steps). Returns the
    keys set, as paths."""
    if "=" not in assignment:
        raise InputError(f"override {assignment!r}: write it as key=value, e.g. optim.lr=1e-4")
    key, text = assignment.split("=", 1)
    parts = key.strip().split(".")
    if not all(parts):
        raise InputError(f"override {assignment!r}: empty key")
    node = values
    for part in parts[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise InputError(f"override {assignment!r}: '{part}' is not a section")
        node = child
    value = parse(text)
    _merge(node, parts[-1], value)
    return [tuple(parts) + path for path in _leaf_paths(value)]


def apply_overrides(values: dict, assignments: list[str], parse) -> None:
    """`apply_override` of each assignment in turn; a key that two of them set (`optim.lr=1
    optim.lr=2`, or `optim.lr=1 'optim={lr: 2}'`) is refused, as a key given twice in a file is."""
    set_by: dict[tuple[str, ...], str] = {}
    for assignment in assignments:
        paths = apply_override(values, assignment, parse)
        for path in paths:
            for earlier_path, earlier in set_by.items():
                common = min(len(path), len(earlier_path))
                if path[:common] == earlier_path[:common]:
                    raise InputError(f"override {assignment!r}: {'.'.join(path[:common])} is also set by {earlier!r}; "
                                     "give each key once")
        set_by.update(dict.fromkeys(paths, assignment))


def _merge(node: dict, key: str, value: Any) -> None:
    """node[key] = value, a mapping merged into a mapping already there, recursively."""
    if isinstance(value, dict) and isinstance(node.get(key), dict):
        for name, item in value.items():
            _merge(node[key], name, item)
    else:
        node[key] = value


def _leaf_paths(value: Any) -> list[tuple[str, ...]]:
    """The key paths within `value` that `_merge` sets: its own place for anything but a mapping."""
    if isinstance(value, dict):
        return [(str(name),) + path for name, item in value.items() for path in _leaf_paths(item)]
    return [()]


def _join(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else str(name)
