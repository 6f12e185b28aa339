"""`lumos3d convert`: rewrite any checkpoint `load_model` reads (ours, a training checkpoint,
VGGT's, AnySplat's) as one of our .safetensors files, optionally in half precision; or a Gaussian
scene (.ply) as a .splat file for WebGL viewers. The suffixes of the input and output choose."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import typer

from lumos3d_cli.cli.console import print_json, say
from lumos3d_cli.cli.interrupts import library_imports
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.output_paths import check_output_path
from lumos3d_cli.io.output_set import OutputSet
from lumos3d_cli.io.weight_dtypes import STORAGE_DTYPE_NAMES
from lumos3d_cli.model.architectures import get_architecture
from lumos3d_cli.model.bundled_models import resolve_checkpoint

EXAMPLES = """
  lumos3d convert runs/low-light/final.safetensors -o lumos3d-low-light.safetensors --dtype float16
  lumos3d convert vggt/model.pt -o vggt-1b.safetensors     [dim]# VGGT-1B in our layout (fresh Gaussian head)[/dim]
  lumos3d convert out/scene.ply -o scene.splat              [dim]# for WebGL .splat viewers (SH degree 0 colour)[/dim]
"""


def _converts_a_scene(source: Path, output: Path, dtype: str, architecture: str | None) -> bool:
    """True for a .ply scene to .splat; False for a checkpoint; InputError for a mix of the two."""
    scene_in, splat_out = source.suffix.lower() == ".ply", output.suffix.lower() == ".splat"
    if scene_in and not splat_out:
        raise InputError(f"{output}: a .ply scene converts to a .splat file; name the output *.splat")
    if splat_out and not scene_in:
        raise InputError(f"{source}: only a Gaussian scene (.ply) converts to .splat")
    if scene_in and (dtype != "float32" or architecture is not None):
        raise InputError("--dtype and --architecture apply to checkpoints, not to a .ply scene")
    if not scene_in and output.suffix != ".safetensors":
        raise InputError(f"{output}: checkpoints are written as .safetensors files; name the output *.safetensors")
    return scene_in


def _written_once(source: Path, output: Path) -> OutputSet:
    """The one file convert writes: never over a file lumos3d did not write, never its input."""
    return OutputSet(output.parent, "convert", f"convert {output.name}", [source]).add_file(output.name)


@contextmanager
def _source_errors() -> Iterator[None]:
    """The library's errors about its `checkpoint` parameter, which is convert's SOURCE argument, not an option."""
    try:
        yield
    except InputError as error:
        if error.parameter != "checkpoint":
            raise
        raise InputError(error.detail) from None


def _scene_to_splat(source: Path, output: Path, as_json: bool) -> None:
    outputs = _written_once(source, output)
    outputs.check()  # a refusal comes before the libraries load; checked again under the lock
    with library_imports():
        from lumos3d_cli.io.ply import read_ply
        from lumos3d_cli.io.splat import write_splat
    with outputs.reserved():
        gaussians = read_ply(source)
        if len(gaussians) == 0:  # a 0-byte .splat is no scene a viewer can open (`render` refuses it too)
            raise InputError(f"{source}: holds no Gaussians; there is nothing to convert")
        with outputs.staged() as staging:
            write_splat(staging.root / output.name, gaussians)
    summary = {"output": str(output), "format": "splat", "gaussians": len(gaussians), "bytes": output.stat().st_size,
               "source_sh_degree": gaussians.sh_degree}
    if as_json:
        print_json(summary)
        return
    say(f"wrote {output} ({len(gaussians):,} Gaussians, {summary['bytes'] / 2**20:.1f} MiB)")
    if gaussians.sh_degree > 0:
        say(f"note: .splat keeps the base colour only; the scene's SH degree {gaussians.sh_degree} view-dependent colour is dropped")


def convert_command(
    source: Path = typer.Argument(..., help="Checkpoint file or folder (ours, VGGT model.pt/.safetensors, AnySplat), or a scene .ply."),
    output: Path = typer.Option(..., "--output", "-o", help="The .safetensors file to write (.splat for a scene)."),
    dtype: str = typer.Option("float32", "--dtype", help=f"Storage precision: {', '.join(STORAGE_DTYPE_NAMES)}."),
    architecture: str | None = typer.Option(None, "--architecture", help="Model size of a foreign (VGGT/AnySplat) checkpoint: tiny, small, base or vggt-1b (default: the first its shapes fit, vggt-1b tried first)."),
    as_json: bool = typer.Option(False, "--json", help="Print the written file's summary as JSON."),
) -> None:
    """Rewrite a checkpoint in lumos3d's format (e.g. float16 to halve it), or a scene .ply as .splat."""
    if _converts_a_scene(source, output, dtype, architecture):
        check_output_path(output, "output")
        _scene_to_splat(source, output, as_json)
        return
    # Checkpoints and scenes are read and written with torch and safetensors (seconds to import):
    # imported here and in `_scene_to_splat`, when the command runs, so that `--help` and a
    # refused scene conversion stay fast.
    with library_imports():
        from lumos3d_cli.io.weight_files import storage_dtype
        from lumos3d_cli.model.checkpoints import save_checkpoint, summarize_checkpoint
        from lumos3d_cli.model.loading import load_model
    storage_dtype(dtype)  # refuse a bad --dtype before the (possibly large) checkpoint is read
    check_output_path(output, "output")
    with _source_errors():
        source = resolve_checkpoint(source)  # a bundled model's name: its file, protected as an input below
    outputs = _written_once(source, output)
    with outputs.reserved():
        with _source_errors():
            model = load_model(source, architecture=get_architecture(architecture) if architecture else None)
        provenance = {key: value for key, value in model.provenance.items() if key not in ("path", "format")}
        provenance["converted_from"] = {"file": Path(source).name, "format": model.provenance.get("format"), "dtype": dtype}
        with outputs.staged() as staging:
            try:
                save_checkpoint(model, staging.root / output.name, provenance, dtype=dtype)
            except InputError as error:  # a tensor beyond --dtype's range: the file it came from
                raise InputError(f"{source}: {error}", parameter=None) from None
    summary = summarize_checkpoint(output)
    if as_json:
        print_json(summary)
    else:
        size = output.stat().st_size / 2**20
        say(f"wrote {output} ({summary.get('architecture')}, {dtype}, {size:.1f} MiB)")
