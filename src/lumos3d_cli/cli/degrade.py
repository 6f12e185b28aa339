"""`lumos3d degrade`: synthesise low-light or over-exposed versions of photos. The job is
`pipeline.degrade_job`; this module parses, shows and prints."""

from __future__ import annotations

from pathlib import Path

import typer

from lumos3d_cli.cli.console import ProgressBars, print_json, progress_bar, say
from lumos3d_cli.cli.interrupts import library_imports
from lumos3d_cli.data.modes import MODES
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.scene_photos import list_photos
from lumos3d_cli.pipeline.degrade_outputs import degrade_outputs

EXAMPLES = """
  lumos3d degrade photos/ -o dark/ --mode low-light --seed 0
  lumos3d degrade photo.jpg -o dark.png --noise
  lumos3d degrade photos/ -o dark/ --noise --colour-cast 1.25 --jpeg-quality 85
  lumos3d degrade photos/ -o bright/ --mode over-exposure --per-image --bit-depth 16
  lumos3d degrade photos/ -o darker/ --exposure 0.02 0.05 --gamma 1.0 1.5 --noise --per-image
"""


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
    colour_cast: float = typer.Option(
        1.0, "--colour-cast", help="Largest wrong white-balance gain: red and blue scaled by [1/G, G] in linear light (1: none)."
    ),
    jpeg_quality: int | None = typer.Option(None, "--jpeg-quality", help="Compress as JPEG at this quality (1-100) before writing."),
    exposure: tuple[float, float] | None = typer.Option(
        None, "--exposure", help="Linear exposure gain range LOW HIGH (default: the mode's, low light 0.05 0.1, over-exposure 5 15)."
    ),
    gamma: tuple[float, float] | None = typer.Option(
        None, "--gamma", help="Tone-curve gamma range LOW HIGH (default: the mode's, low light 1.3 1.4, over-exposure 1.5 2)."
    ),
    json_output: bool = typer.Option(False, "--json", help="Print a JSON summary on stdout."),
) -> None:
    """Synthesise low-light (the paper's model) or over-exposed images from normal-light ones."""
    if mode not in MODES:
        raise InputError(f"--mode {mode!r}: use one of {', '.join(MODES)}")
    paths = list_photos(inputs)
    outputs = degrade_outputs(paths, output, bit_depth, inputs)
    outputs.check()  # a refusal comes before the libraries load (about 2 s); checked again under the lock
    # The job imports torch, OpenCV and the image readers (seconds): imported here, when the
    # command runs, so that `--help` and a refused command line stay fast.
    with library_imports():
        from lumos3d_cli.pipeline.degrade_job import degrade_files
    with outputs.reserved(), progress_bar() as bars:
        summary = degrade_files(paths, output, mode, seed, noise, per_image, bit_depth, ProgressBars(bars),
                                colour_cast, jpeg_quality, exposure, gamma, inputs)
    if json_output:
        print_json(summary)
    else:
        say(f"wrote {summary['count']} {mode} image(s) to {output}")
