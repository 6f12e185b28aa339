"""No module imports from a layer above its own. The layers follow the data flow: files and shared
helpers at the bottom, then the network, geometry, rendering, losses, data, evaluation, training,
the jobs, the viewer, and the command line on top."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "lumos3d_cli"
ROOT_MODULES = ("errors", "checks", "rotations", "tensors", "typed_config", "__init__")  # layer 0: shared by all
LAYERS = ("<root>", "io", "model", "geometry", "render", "losses", "refine", "data", "eval", "train", "pipeline", "viewer", "cli")
ENTRY_POINTS = {"__main__": "cli"}  # `python -m lumos3d_cli` runs the CLI


def layer_of(module: str) -> str:
    """The layer of a dotted module name inside lumos3d_cli ("lumos3d_cli.model.lumos3d" -> "model")."""
    parts = module.split(".")[1:]
    if not parts or parts[0] in ROOT_MODULES:
        return "<root>"
    if parts[0] in ENTRY_POINTS:
        return ENTRY_POINTS[parts[0]]
    if parts[0] not in LAYERS:
        raise AssertionError(f"lumos3d_cli.{parts[0]} belongs to no layer: add it to LAYERS in tests/test_layers.py")
    return parts[0]


def imported_modules(source: str, module: str) -> list[str]:
    """Every lumos3d_cli module `source` imports (relative imports resolved against `module`)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")[: -node.level]
                source_module = ".".join(base + ([node.module] if node.module else []))
            else:
                source_module = node.module or ""
            found.append(source_module)
            if source_module == "lumos3d_cli":  # `from lumos3d_cli import pipeline` imports the package pipeline
                found += [f"lumos3d_cli.{alias.name}" for alias in node.names]
    return [name for name in found if name == "lumos3d_cli" or name.startswith("lumos3d_cli.")]


def upward_imports(source: str, module: str) -> list[str]:
    """The imports of `module` (its source text) that reach a layer above its own."""
    own = LAYERS.index(layer_of(module))
    return [f"{module} imports {name} ({layer_of(name)} is above {layer_of(module)})"
            for name in imported_modules(source, module) if LAYERS.index(layer_of(name)) > own]


def _modules() -> list[tuple[str, Path]]:
    modules = []
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        modules.append((".".join(parts[:-1] if parts[-1] == "__init__" else parts), path))
    return modules


@pytest.mark.parametrize("module, path", _modules(), ids=[name for name, _ in _modules()])
def test_no_module_imports_from_a_layer_above(module, path):
    if path.name == "__init__.py":
        module = module + ".__init__"  # a package's own relative imports resolve inside it
    assert upward_imports(path.read_text(), module) == []


@pytest.mark.parametrize("source, module, expected", [
    ("from lumos3d_cli.train.config import LossConfig", "lumos3d_cli.losses.objective", 1),
    ("import lumos3d_cli.cli.app", "lumos3d_cli.io.images", 1),
    ("from ..pipeline import restore", "lumos3d_cli.model.loading", 1),
    ("from lumos3d_cli.io.images import load_images", "lumos3d_cli.model.loading", 0),
    ("from lumos3d_cli.errors import InputError", "lumos3d_cli.io.images", 0),
    ("from lumos3d_cli.model.lumos3d import Lumos3D", "lumos3d_cli.io.images", 1),
    ("from lumos3d_cli import pipeline", "lumos3d_cli.model.loading", 1),  # the package itself
    ("from .. import cli", "lumos3d_cli.io.images", 1),
    ("from lumos3d_cli import errors", "lumos3d_cli.io.images", 0),
])
def test_the_check_catches_an_upward_import(source, module, expected):
    assert len(upward_imports(source, module)) == expected


def test_an_unknown_package_must_be_placed():
    with pytest.raises(AssertionError, match="belongs to no layer"):
        layer_of("lumos3d_cli.newstage.thing")
