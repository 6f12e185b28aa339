"""`lumos3d degrade`: synthesise low-light or over-exposed versions of photos."""

from __future__ import annotations

import json
import time
from pathlib import Path

import torch
import typer

from lumos3d_cli.cli.console import print_json, progress_bar, say
from lumos3d_cli.data.degradations import MODES, Degradation, apply_degradation, sample_parameters
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import atomic_directory
from lumos3d_cli.io.image_files import PHOTO_SUFFIXES, list_images
from lumos3d_cli.io.image_write import write_image
from lumos3d_cli.io.images import read_image, to_srgb
from lumos3d_cli.io.output_paths import check_output_path

EXAMPLES = """
  lumos3d degrade photos/ -o dark/ --mode low-light --seed 0
  lumos3d degrade photo.jpg -o dark.png --noise
  lumos3d degrade photos/ -o bright/ --mode over-exposure --per-image --bit-depth 16
"""

_SINGLE_FILE_SUFFIXES = (".png", ".jpg", ".jpeg")  # what io.image_write encodes


def _check_output(inputs: list[Path], output: Path, bit_depth: int) -> bool:
    """Validate -o before any image is read; True when it names a single output file rather than
    a folder. Messages name the user's path (the files are written under temporary names)."""
    suffix = output.suffix.lower()
    if suffix in PHOTO_SUFFIXES:
        if len(inputs) != 1:
            raise InputError(f"{output}: names one file but there are {len(inputs)} inputs; pass a folder to -o")
        if suffix not in _SINGLE_FILE_SUFFIXES:
            raise InputError(f"{output}: cannot write '{output.suffix}' files; use .png or .jpg")
        if bit_depth != 8 and suffix != ".png":
            raise InputError(f"{output}: JPEG holds 8 bits only; use .png for 16-bit output")
        check_output_path(output, "output")
        return True
    check_output_path(output, "output", folder=True)
    return False


def degrade_command(
    inputs: list[Path] = typer.Argument(..., help="Image files or folders (photos, RAW, EXR)."),
    output: Path = typer.Option(..., "--output", "-o", help="Output folder, or a .png/.jpg file for one input."),
    mode: str = typer.Option("low-light", "--mode", help=f"One of: {', '.join(MODES)}."),
    seed: int = typer.Option(0, "--seed", help="Random seed; the same seed gives the same output."),
    noise: bool = typer.Option(False, "--noise/--no-noise", help="Add shot + read sensor noise (off by default)."),
    per_image: bool = typer.Option(
        False, "--per-image", help="Draw exposure/gamma per image (default: one draw shared by all, like one camera setting)."
    ),
    bit_depth: int = typer.Option(8, "--bit-depth", help="8 or 16 bits per channel (16 needs .png)."),
    json_output: bool = typer.Option(False, "--json", help="Print a JSON summary on stdout."),
) -> None:
    """Synthesise low-light (the paper's model) or over-exposed images from normal-light ones."""
    if mode not in MODES:
        raise InputError(f"--mode {mode!r}: use one of {', '.join(MODES)}")
    if bit_depth not in (8, 16):
        raise InputError(f"--bit-depth {bit_depth}: use 8 or 16")
    paths = list_images(inputs)
    single_file = _check_output(paths, output, bit_depth)
    degradation = Degradation(mode, noise=noise)
    generator = torch.Generator().manual_seed(seed)
    shared = None if per_image else sample_parameters(degradation, (), generator)
    started = time.perf_counter()
    records = []
    # Everything is written into a staging folder and moved into place only when all succeeded.
    with atomic_directory(output.parent if single_file else output) as staging, progress_bar() as progress:
        task = progress.add_task(f"degrade ({mode})", total=len(paths))
        for source in paths:
            target = output if single_file else output / f"{source.stem}.png"
            image = torch.from_numpy(to_srgb(read_image(source))).permute(2, 0, 1)
            parameters = shared if shared is not None else sample_parameters(degradation, (), generator)
            degraded = apply_degradation(image, mode, parameters, generator)
            write_image(staging / target.name, degraded.permute(1, 2, 0).numpy(), bit_depth=bit_depth)
            records.append({"input": str(source), "output": str(target), **parameters.as_dict()})
            progress.advance(task)
        summary = {
            "mode": mode, "seed": seed, "noise": noise, "shared_parameters": not per_image,
            "count": len(records), "seconds": round(time.perf_counter() - started, 3), "images": records,
        }
        if not single_file:
            (staging / "degradation.json").write_text(json.dumps(summary, indent=2) + "\n")
    if json_output:
        print_json(summary)
    else:
        say(f"wrote {len(records)} {mode} image(s) to {output}")
