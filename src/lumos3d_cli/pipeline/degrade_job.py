"""The degrade job: photos on disk -> synthetic low-light or over-exposed copies on disk (a folder
with degradation.json, or one file), all or nothing."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import torch

from lumos3d_cli.data.degradations import (
    MAX_COLOUR_CAST, MODES, Degradation, apply_degradation, is_valid_range, range_rule, sample_parameters,
)
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.image_write import DEFAULT_JPEG_QUALITY, JPEG_MAX_SIDE, PNG_MAX_SIDE, write_image
from lumos3d_cli.io.images import read_image, to_srgb
from lumos3d_cli.pipeline.degrade_outputs import degrade_outputs, is_single_file
from lumos3d_cli.pipeline.progress import JobProgress, SilentProgress

def degrade_files(
    paths: list[Path], output: Path, mode: str = "low-light", seed: int = 0, noise: bool = False,
    per_image: bool = False, bit_depth: int = 8, progress: JobProgress | None = None,
    colour_cast: float = 1.0, jpeg_quality: int | None = None,
    exposure: tuple[float, float] | None = None, gamma: tuple[float, float] | None = None,
    given: Sequence[Path] = (),
) -> dict:
    """Degrade every photo in `paths` into `output` (a folder of PNGs plus degradation.json, or one
    .png/.jpg for one input) and return the summary: the parameters drawn for each image. One draw
    is shared by all images (one camera setting) unless `per_image`. The camera-pipeline stages of
    training are available too: `colour_cast` g draws red and blue linear gains in [1/g, g];
    `jpeg_quality` compresses at that quality before writing; `exposure` and `gamma` (low, high)
    replace the mode's documented ranges (data.degradations.DOCUMENTED_RANGES), as a training
    config's `degrade` section does. The outputs never touch the inputs or the folders `given`
    for them, nor a file lumos3d did not write (io/output_set.py)."""
    progress = progress or SilentProgress()
    if mode not in MODES:
        raise InputError(f"{mode!r}: use one of {', '.join(MODES)}", parameter="mode")
    if not 0 <= seed < 2**63:  # as a training config's seed: torch's generator wraps others round silently
        raise InputError(f"{seed}: use a seed from 0 to 2**63 - 1", parameter="seed")
    outputs = degrade_outputs(paths, output, bit_depth, given)
    outputs.check()
    single_file = is_single_file(output)
    if not (math.isfinite(colour_cast) and 1 <= colour_cast <= MAX_COLOUR_CAST):
        raise InputError(f"{colour_cast}: the largest colour-cast gain must be from 1 (no cast) to {MAX_COLOUR_CAST:g}",
                         parameter="colour_cast")
    if jpeg_quality is not None and not 1 <= jpeg_quality <= 100:
        raise InputError(f"{jpeg_quality}: use a JPEG quality from 1 to 100", parameter="jpeg_quality")
    if jpeg_quality is not None and bit_depth != 8:
        raise InputError(f"{jpeg_quality}: JPEG compression leaves 8 bits a channel; use it with 8-bit output",
                         parameter="jpeg_quality")
    for name, bounds in (("exposure", exposure), ("gamma", gamma)):
        if bounds is not None and not is_valid_range(bounds, name):
            raise InputError(f"{bounds[0]} {bounds[1]}: the {name} range needs {range_rule(name)}", parameter=name)
    degradation = Degradation(mode, exposure=exposure, gamma=gamma, noise=noise, colour_cast=(1 / colour_cast, colour_cast),
                              jpeg_quality=None if jpeg_quality is None else (jpeg_quality, jpeg_quality))
    ranges = degradation.ranges(mode)
    generator = torch.Generator().manual_seed(seed)
    shared = None if per_image else sample_parameters(degradation, (), generator)
    started = time.perf_counter()
    records = []
    progress.start(f"degrade ({mode})", len(paths))
    # a .jpg output is the JPEG stage itself: compressed once, at --jpeg-quality (else write_image's default)
    writes_jpeg = single_file and output.suffix.lower() in (".jpg", ".jpeg")
    file_quality = jpeg_quality or DEFAULT_JPEG_QUALITY  # a PNG ignores it
    with outputs.staged() as staging:
        for source in paths:
            target = output if single_file else output / f"{source.stem}.png"
            image = torch.from_numpy(to_srgb(read_image(source))).permute(2, 0, 1)
            if (writes_jpeg or jpeg_quality is not None) and max(image.shape[1:]) > JPEG_MAX_SIDE:
                raise InputError(f"{source}: {image.shape[2]}x{image.shape[1]} pixels; JPEG holds at most {JPEG_MAX_SIDE} "
                                 "a side: degrade it without JPEG (no --jpeg-quality, a .png output)")
            if max(image.shape[1:]) > PNG_MAX_SIDE:
                raise InputError(f"{source}: {image.shape[2]}x{image.shape[1]} pixels; a PNG written here holds at most "
                                 f"{PNG_MAX_SIDE:,} a side: crop or downscale it")
            parameters = shared if shared is not None else sample_parameters(degradation, (), generator)
            degraded = apply_degradation(image, mode, replace(parameters, jpeg_quality=None) if writes_jpeg else parameters,
                                         generator)
            write_image(staging.root / target.name, degraded.permute(1, 2, 0).numpy(), bit_depth=bit_depth,
                        jpeg_quality=file_quality)
            drawn = parameters.as_dict()
            if writes_jpeg:
                drawn.update(jpeg_quality=float(file_quality), bits=8)
            records.append({"input": str(source), "output": str(target), **drawn})
            progress.advance(f"degrade ({mode})")
        summary = {
            "mode": mode, "seed": seed, "exposure_range": list(ranges.exposure), "gamma_range": list(ranges.gamma),
            "noise": noise, "colour_cast": colour_cast, "jpeg_quality": file_quality if writes_jpeg else jpeg_quality,
            "shared_parameters": not per_image, "bit_depth": 8 if writes_jpeg else bit_depth,
            "count": len(records), "seconds": round(time.perf_counter() - started, 3), "images": records,
        }
        if not single_file:
            (staging.root / "degradation.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary
