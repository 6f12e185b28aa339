"""`lumos3d convert`: rewrite any checkpoint `load_model` reads (ours, a training checkpoint,
VGGT's, AnySplat's) as one of our .safetensors files, optionally in half precision."""

from __future__ import annotations

from pathlib import Path

import typer

from lumos3d_cli.cli.console import print_json, say
from lumos3d_cli.io.weight_files import STORAGE_DTYPES, storage_dtype
from lumos3d_cli.model.architectures import get_architecture
from lumos3d_cli.model.checkpoints import save_checkpoint, summarize_checkpoint
from lumos3d_cli.model.loading import load_model

EXAMPLES = """
  lumos3d convert runs/low-light/final.safetensors -o lumos3d-low-light.safetensors --dtype float16
  lumos3d convert vggt/model.pt -o vggt-1b.safetensors     [dim]# VGGT-1B in our layout (fresh Gaussian head)[/dim]
"""


def convert_command(
    source: Path = typer.Argument(..., help="Checkpoint file or folder (ours, VGGT model.pt/.safetensors, AnySplat)."),
    output: Path = typer.Option(..., "--output", "-o", help="The .safetensors file to write."),
    dtype: str = typer.Option("float32", "--dtype", help=f"Storage precision: {', '.join(STORAGE_DTYPES)}."),
    architecture: str | None = typer.Option(None, "--architecture", help="Model size of a foreign (VGGT/AnySplat) checkpoint: tiny, small, base or vggt-1b (default)."),
    as_json: bool = typer.Option(False, "--json", help="Print the written checkpoint's summary as JSON."),
) -> None:
    """Rewrite a checkpoint in lumos3d's format (e.g. float16 to halve it)."""
    storage_dtype(dtype)  # refuse a bad --dtype before the (possibly large) checkpoint is read
    model = load_model(source, architecture=get_architecture(architecture) if architecture else None)
    provenance = {key: value for key, value in model.provenance.items() if key not in ("path", "format")}
    provenance["converted_from"] = {"file": Path(source).name, "format": model.provenance.get("format"), "dtype": dtype}
    save_checkpoint(model, output, provenance, dtype=dtype)
    summary = summarize_checkpoint(output)
    if as_json:
        print_json(summary)
    else:
        size = output.stat().st_size / 2**20
        say(f"wrote {output} ({summary.get('architecture')}, {dtype}, {size:.1f} MiB)")
