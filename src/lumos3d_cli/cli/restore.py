"""`lumos3d restore`: photos taken in the dark (or over-exposed) -> a restored 3D Gaussian scene,
its cameras, the restored views, a contact sheet, a preview and a summary."""

from __future__ import annotations

import json
import resource
import time
from pathlib import Path

import numpy as np
import torch
import typer

from lumos3d_cli.cli.console import print_json, progress_bar, say
from lumos3d_cli.data.degradations import MODES
from lumos3d_cli.errors import InputError
from lumos3d_cli.eval.contact_sheet import contact_sheet
from lumos3d_cli.io.atomic import atomic_directory
from lumos3d_cli.io.colmap import write_colmap_model
from lumos3d_cli.io.colour import srgb_to_linear
from lumos3d_cli.io.image_files import list_images
from lumos3d_cli.io.image_write import write_exr, write_image
from lumos3d_cli.io.images import load_images
from lumos3d_cli.io.ply import write_ply
from lumos3d_cli.io.preview_glb import write_preview_glb
from lumos3d_cli.io.transforms_json import write_transforms_json
from lumos3d_cli.pipeline.presets import DEFAULT_RESTORE_PRESET, get_restore_preset
from lumos3d_cli.pipeline.quality import QualityMeter, mean_metrics
from lumos3d_cli.pipeline.restore import file_sha256, load_restoration_model, resolve_checkpoint, restore_scene

EXAMPLES = """
  lumos3d restore photos/ -o out/scene.ply
  lumos3d restore dark/ -o out/scene.ply --preset best --reference bright/ --lpips-weights vgg16-397923af.pth
  lumos3d restore raw/*.dng -o out/scene.ply --checkpoint lumos3d.safetensors --output-format exr
"""

_FORMATS = {"png": (".png", 8), "png16": (".png", 16), "exr": (".exr", 0)}


def _references(folder: Path, names: list[str], size: tuple[int, int]) -> torch.Tensor:
    """Reference photos with the same file stems as the restored views, [V, 3, H, W]."""
    if not folder.is_dir():
        raise InputError(f"--reference {folder}: no such folder")
    available = {p.stem: p for p in list_images(folder)}
    paths = []
    for name in names:
        stem = Path(name).stem
        if stem not in available:
            raise InputError(f"--reference {folder}: no image named {stem}.* for input {name}")
        paths.append(available[stem])
    batch = load_images(paths)
    if batch.size != size or len(set(batch.original_sizes)) != 1:
        raise InputError(
            f"--reference {folder}: images are {batch.original_sizes[0][0]}x{batch.original_sizes[0][1]}, "
            f"the inputs {size[0]}x{size[1]}; give references of the same size"
        )
    return batch.images


def _write_view(path: Path, image: torch.Tensor, output_format: str) -> None:
    pixels = image.permute(1, 2, 0).numpy()
    if output_format == "exr":
        write_exr(path, srgb_to_linear(np.clip(pixels, 0, 1)))
    else:
        write_image(path, pixels, bit_depth=_FORMATS[output_format][1])


def restore_command(
    photos: list[Path] = typer.Argument(..., help="A folder or files: photos, camera RAW, EXR."),
    output: Path = typer.Option(..., "--output", "-o", help="The scene file to write (.ply); everything else goes beside it."),
    checkpoint: Path | None = typer.Option(None, "--checkpoint", help="Model weights (default: the bundled model of --mode)."),
    preset: str = typer.Option(DEFAULT_RESTORE_PRESET, "--preset", help="fast, balanced or best."),
    mode: str = typer.Option("low-light", "--mode", help=f"One of: {', '.join(MODES)}."),
    max_views: int | None = typer.Option(None, "--max-views", help="Views the network sees (default: the preset's)."),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    reference: Path | None = typer.Option(None, "--reference", help="Normal-light photos of the same views (metrics)."),
    lpips_weights: Path | None = typer.Option(None, "--lpips-weights", help="torchvision vgg16 weights for LPIPS."),
    output_format: str = typer.Option("png", "--output-format", help="Restored views as png (8-bit), png16 or exr (linear)."),
    json_output: bool = typer.Option(False, "--json", help="Print the summary as JSON on stdout."),
) -> None:
    """Restore a 3D scene from unposed low-light or over-exposed photos in one forward pass."""
    started = time.perf_counter()
    if output.suffix.lower() != ".ply":
        raise InputError(f"-o {output}: the scene file must end in .ply")
    if mode not in MODES:
        raise InputError(f"--mode {mode!r}: use one of {', '.join(MODES)}")
    if device not in ("cpu", "cuda"):
        raise InputError(f"--device {device!r}: use cpu or cuda")
    if output_format not in _FORMATS:
        raise InputError(f"--output-format {output_format!r}: use png, png16 or exr")
    if max_views is not None and max_views < 1:
        raise InputError(f"--max-views {max_views}: use at least 1")
    settings = get_restore_preset(preset)
    weights = resolve_checkpoint(checkpoint, mode)
    meter = QualityMeter.create(lpips_weights) if reference is not None else None
    timings: dict[str, float] = {}
    with progress_bar() as progress:
        paths = list_images(photos)
        load_task = progress.add_task("load images", total=len(paths))
        stage_started = time.perf_counter()
        batch = load_images(paths, progress=lambda _: progress.advance(load_task))
        timings["load"] = time.perf_counter() - stage_started
        stage_started = time.perf_counter()
        model = load_restoration_model(weights, device)
        timings["load_model"] = time.perf_counter() - stage_started
        network_task = progress.add_task("network", total=1)
        render_task = progress.add_task("render views", total=min(len(paths), max_views or settings.max_views))
        scene = restore_scene(
            batch, model, settings, max_views,
            on_stage=lambda stage: progress.update(network_task, completed=1) if stage == "render" else None,
            on_view=lambda: progress.advance(render_task),
        )
        timings.update(scene.timings)
        names = scene.cameras.names
        metrics = None
        if reference is not None:
            references = _references(reference, names, batch.size)
            per_view = meter.measure(scene.restored, references)
            metrics = {"views": dict(zip(names, per_view)), "mean": mean_metrics(per_view), "lpips_note": meter.lpips_note}
        write_task = progress.add_task("write outputs", total=1)
        stage_started = time.perf_counter()
        suffix = _FORMATS[output_format][0]
        with atomic_directory(output.parent) as staging:
            write_ply(staging / output.name, scene.gaussians)
            write_transforms_json(staging / "cameras.json", scene.cameras)
            write_colmap_model(staging / "colmap", scene.cameras)
            (staging / "restored").mkdir()
            for name, image in zip(names, scene.restored):
                _write_view(staging / "restored" / f"{Path(name).stem}{suffix}", image, output_format)
            rows = []
            for index, name in enumerate(names):
                row = [(scene.inputs[index], f"input {name}"), (scene.restored[index], "restored")]
                if metrics is not None:
                    values = metrics["views"][name]
                    row[1] = (scene.restored[index], f"restored  PSNR {values['psnr']:.2f}  SSIM {values['ssim']:.3f}")
                    row.append((references[index], "reference"))
                rows.append(row)
            write_image(staging / "contact_sheet.png", contact_sheet(rows).astype(np.float32) / 255)
            write_preview_glb(staging / "preview.glb", scene.gaussians, scene.cameras)
            timings["write"] = time.perf_counter() - stage_started
            summary = {
                "scene": str(output), "inputs": len(paths), "views_used": len(names), "views": names,
                "network_size": list(scene.network_size), "preset": settings.name, "mode": mode, "device": device,
                "checkpoint": {"name": weights.name, "sha256": file_sha256(weights)},
                "gaussians": {"pixel": scene.counts.pixels, "voxels": scene.counts.voxels,
                              "pruned": scene.counts.pruned, "kept": len(scene.gaussians)},
                "seconds": {k: round(v, 3) for k, v in timings.items()} | {"total": round(time.perf_counter() - started, 3)},
                "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
                "metrics": metrics,
            }
            (staging / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        progress.update(write_task, completed=1)
    if json_output:
        print_json(summary)
    else:
        say(f"restored {len(names)} view(s): {output} ({len(scene.gaussians):,} Gaussians), views in "
            f"{output.parent / 'restored'}, contact sheet {output.parent / 'contact_sheet.png'}")
