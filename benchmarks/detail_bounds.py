"""Where a restored view's decibels go (issues 35 and 36), on the LOM development scenes: the
bundled operator applied in 2D to each test frame's own photo (what colour restoration alone
reaches, no 3D), the same image carried by a grid of one Gaussian per network pixel (area-
downsampled to the grid, bilinear back: the most detail such a scene can hold), and the restored
scene's render (`lumos3d eval`, context and holdout). The gap from the first to the second is
what the Gaussian grid costs, from the second to the render what fusion and refinement lose;
the gamma curve is the blind baseline.

    .venv/bin/python benchmarks/detail_bounds.py               # the table, into docs/model-card.md
    .venv/bin/python benchmarks/detail_bounds.py --no-renders  # the 2D rows only (seconds), no doc

The operator is the one `restore` predicts at the preset (the network sees the test frames, so
each has its local gain grid), with the exposure prior; evaluation only, nothing is chosen here.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from pathlib import Path

import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import SHARED_DATA, markdown_table, table_section, write_section  # noqa: E402

from lumos3d_cli.data.lom import read_lom_scene  # noqa: E402
from lumos3d_cli.eval.appearance_stats import appearance_stats  # noqa: E402
from lumos3d_cli.eval.metrics import auto_gamma, psnr, sharpness, ssim  # noqa: E402
from lumos3d_cli.io.images import load_images  # noqa: E402
from lumos3d_cli.model.bundled_models import resolve_checkpoint  # noqa: E402
from lumos3d_cli.model.loading import load_model  # noqa: E402
from lumos3d_cli.pipeline.evaluation import evaluate_lom  # noqa: E402
from lumos3d_cli.pipeline.gaussian_grid import dense_grid_size  # noqa: E402
from lumos3d_cli.pipeline.network_pass import even_subset, run_network  # noqa: E402
from lumos3d_cli.pipeline.presets import get_restore_preset  # noqa: E402
from lumos3d_cli.pipeline.scene_stages import operator_restoration  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MODEL_CARD = REPO / "docs" / "model-card.md"
SHARED = SHARED_DATA
SCENES = ("buu", "shrub")
MODES = ("low-light", "over-exposure")
GRIDS = (1.0, 2.0)

logger = logging.getLogger("detail_bounds")


def through_grid(images: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """images [V, 3, H, W] -> the same carried by a grid of `size` (width, height): area-averaged
    onto the grid (each cell's mean colour) and bilinearly back to H x W."""
    width, height = size
    coarse = F.interpolate(images, size=(height, width), mode="area")
    return F.interpolate(coarse, size=images.shape[-2:], mode="bilinear", align_corners=False).clamp(0.0, 1.0)


def scores(images: torch.Tensor, references: torch.Tensor) -> dict[str, float]:
    """Mean PSNR, SSIM and sharpness of images [V, 3, H, W] against references, and the chroma
    ratio as the development benchmark's (benchmarks/appearance_dev.py): the mean output chroma
    over the mean reference chroma."""
    stats = appearance_stats(images, references)
    return {
        "psnr": float(psnr(images, references).mean()), "ssim": float(ssim(images, references).mean()),
        "sharpness": float(sharpness(images, references).mean()),
        "chroma_ratio": sum(row["chroma"] for row in stats) / sum(row["chroma_reference"] for row in stats),
    }


def bounds_2d(scene_name: str, mode: str, preset_name: str) -> dict[str, dict[str, float]]:
    """The 2D rows of one scene and mode: gamma, the operator at the photos' size and through
    each Gaussian grid of GRIDS."""
    scene = read_lom_scene(SHARED / "lom" / scene_name, mode)
    photos = load_images([scene.degraded[frame] for frame in scene.frames]).images
    references = load_images([scene.reference[frame] for frame in scene.test]).images
    preset = get_restore_preset(preset_name)
    model = load_model(resolve_checkpoint(None, mode))
    test = [scene.frames.index(frame) for frame in scene.test]
    selected = even_subset(len(scene.frames), preset.max_views, required=test)
    network = run_network(model, photos[selected], preset, mode)
    restored = operator_restoration(network, photos, selected)[test].clamp(0.0, 1.0)
    photo_size = (photos.shape[-1], photos.shape[-2])
    rows = {"gamma curve": scores(auto_gamma(photos[test]), references),
            "operator, 2D at the photos' size": scores(restored, references)}
    for grid in GRIDS:
        size = dense_grid_size(network.network_size, photo_size, grid)
        rows[f"operator through a grid of {size[0]}x{size[1]}"] = scores(through_grid(restored, size), references)
    return rows


def render_rows(scene_name: str, mode: str, preset_name: str) -> dict[str, dict[str, float]]:
    """`lumos3d eval`'s render of the scene at the preset, both protocols, scored as the 2D rows."""
    rows = {}
    for protocol in ("context", "holdout"):
        result = evaluate_lom(SHARED / "lom", [scene_name], mode, protocol, preset=preset_name).scenes[0]
        renders = torch.stack(list(result.renders))
        rows[f"render, {protocol}"] = scores(renders, torch.stack(list(result.references)))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="balanced")
    parser.add_argument("--no-renders", action="store_true", help="only the 2D rows (no eval, no doc update)")
    parser.add_argument("--no-doc", action="store_true", help="do not rewrite the model-card section")
    options = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    torch.set_num_threads(min(2, os.cpu_count() or 1))
    started = time.perf_counter()
    rows = []
    for mode in MODES:
        for scene_name in SCENES:
            measured = bounds_2d(scene_name, mode, options.preset)
            if not options.no_renders:
                measured |= render_rows(scene_name, mode, options.preset)
            for label, values in measured.items():
                rows.append([mode, scene_name, label, f"{values['psnr']:.2f} / {values['ssim']:.3f}",
                             f"{values['sharpness']:.2f}", f"{values['chroma_ratio']:.2f}"])
    table = markdown_table(["mode", "scene", "image", "PSNR / SSIM", "sharpness", "chroma ratio"], rows)
    print(table)
    print(f"\n{(time.perf_counter() - started) / 60:.1f} min")
    if options.no_renders or options.no_doc:
        return
    text = table_section(
        "### Where the decibels go: the operator, the Gaussian grid, the scene",
        f"`lumos3d eval`'s test frames of LOM buu (3) and shrub (5), each mode, `{options.preset}`. "
        "\"operator, 2D\": the bundled operator applied to each test frame's own photo, as `restore` predicts "
        "it (the network sees the test frames, so each has its local grid; the exposure prior included), "
        "no 3D. \"through a grid\": that image area-averaged onto a grid of one Gaussian per network pixel "
        "(and per half pixel: `--gaussian-grid 2`) and bilinear back, the most detail a scene of that grid "
        "can hold. \"render\": the restored scene at the test camera (context: the test photos among the "
        "fitted views; holdout: left out). Chroma ratio: `eval/appearance_stats.py` (1 is the reference's "
        "saturation). Written by `benchmarks/detail_bounds.py`.",
        table,
    )  # fmt: skip
    write_section("detail-bounds", text, MODEL_CARD)


if __name__ == "__main__":
    main()
