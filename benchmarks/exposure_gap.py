"""How much of the bundled illumination head's PSNR shortfall is overall exposure: the head's
restoration of each scene's photos (2D, the operator applied at full resolution, no 3D), scored
as it is, after one brightness scale per scene, after one per view (both fitted to the ground
truth in linear light by least squares) and at the ground truth's mean grey (`psnr_gt_mean`, the
GT-mean protocol `lumos3d eval` reports).

One scale per scene is the part a dark photo cannot reveal (how bright the reference was
exposed); one per view adds each photo's own exposure. What remains after them is colour,
contrast, noise and detail. Data: the 20 held-out SICE brackets (every pair of the mode's
pairing rule, one pair = one one-view scene) and, for reference only (never used to choose
anything), LOM buu: the operator predicted from all its photos (as `balanced` does), scored at
its transforms_test.json frames.

    .venv/bin/python benchmarks/exposure_gap.py            # prints the table, rewrites the model-card section
    .venv/bin/python benchmarks/exposure_gap.py --limit 3  # a quick look at 3 pairs (no doc update)
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import SHARED_DATA, markdown_table, table_section, write_section  # noqa: E402

from lumos3d_cli.data.brackets import bracket_pairs, read_srgb  # noqa: E402
from lumos3d_cli.data.lom import read_lom_scene  # noqa: E402
from lumos3d_cli.eval.metrics import psnr, psnr_gt_mean  # noqa: E402
from lumos3d_cli.io.colour import linear_to_srgb, srgb_to_linear  # noqa: E402
from lumos3d_cli.model.appearance.photo_restoration import restore_photos  # noqa: E402
from lumos3d_cli.model.bundled_models import resolve_checkpoint  # noqa: E402
from lumos3d_cli.model.loading import load_model  # noqa: E402
from lumos3d_cli.model.lumos3d import Lumos3D  # noqa: E402
from lumos3d_cli.model.preprocess import prepare_images  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MODEL_CARD = REPO / "docs" / "model-card.md"
SHARED = SHARED_DATA
COLUMNS = ("as restored", "one scale per scene", "one scale per view", "at GT mean grey")

logger = logging.getLogger("exposure_gap")


def _scaled(restored: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """restored sRGB [V, 3, H, W], scale [V] or [] in linear light -> sRGB, clipped."""
    return linear_to_srgb((srgb_to_linear(restored) * scale.reshape(-1, 1, 1, 1)).clamp(0, 1))


def _least_squares_scale(restored: torch.Tensor, target: torch.Tensor, dims: tuple[int, ...]) -> torch.Tensor:
    """The scale s minimising |s * restored - target|^2 in linear light, summed over `dims`."""
    ours, theirs = srgb_to_linear(restored).double(), srgb_to_linear(target).double()
    return (ours * theirs).sum(dims) / (ours * ours).sum(dims).clamp_min(1e-12)


def score_scene(model: Lumos3D, photos: torch.Tensor, scored: list[int], targets: torch.Tensor) -> list[list[float]]:
    """photos [V, 3, H, W] sRGB (the scene's degraded photos; the operator is predicted from all
    of them), scored: the views with ground truth targets [S, 3, H, W] -> per scored view, the
    PSNR of each of COLUMNS."""
    image_size = model.architecture.image_size
    network = prepare_images(photos, image_size, model.architecture.patch_size).images
    with torch.no_grad():
        operator = model.predict_appearance(network[None]).scene(0)
        # only the scored views: their own local grids, the scene's curve and matrix
        restored = restore_photos(photos[scored], operator.views(torch.tensor(scored)))
    per_scene = _least_squares_scale(restored, targets, (0, 1, 2, 3))
    per_view = _least_squares_scale(restored, targets, (1, 2, 3))
    return torch.stack([
        psnr(restored, targets), psnr(_scaled(restored, per_scene), targets), psnr(_scaled(restored, per_view), targets),
        psnr_gt_mean(restored, targets),
    ], dim=1).tolist()  # fmt: skip


def _means(scores: list[list[float]]) -> list[str]:
    return [f"{sum(column) / len(column):.2f}" for column in zip(*scores)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--limit", type=int, default=None, help="at most this many bracket pairs (quick look; no doc update)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    torch.set_num_threads(1)  # small one-view scenes: threads only contend
    rows = []
    for mode in ("low-light", "over-exposure"):
        model = load_model(resolve_checkpoint(None, mode)).eval()
        pairs = bracket_pairs(SHARED / "brackets", mode, "validation")[: args.limit]
        scores = []
        for pair in pairs:
            scores += score_scene(model, read_srgb(pair.input_path)[None], [0], read_srgb(pair.target_path)[None])
        rows.append([f"SICE held-out, {mode} ({len(pairs)} pairs)", *_means(scores)])
        scene = read_lom_scene(SHARED / "lom" / "buu", mode)
        photos = torch.stack([read_srgb(scene.degraded[frame]) for frame in scene.frames])
        targets = torch.stack([read_srgb(scene.reference[frame]) for frame in scene.test])
        scored = [scene.frames.index(frame) for frame in scene.test]
        rows.append([f"LOM buu, {mode} ({len(scored)} test frames; reference)", *_means(score_scene(model, photos, scored, targets))])
        logger.info("%s", rows[-2:])
    table = markdown_table(["PSNR dB, bundled head (2D)", *COLUMNS], rows)
    print(table)
    if args.limit is not None:
        return
    text = table_section(
        "### Where the PSNR goes: overall exposure",
        "Each bundled model's illumination head restores a scene's photos in 2D (the operator at full "
        "resolution, no 3D); the restored views are scored as they are, after one brightness scale per "
        "scene, after one per view (both fitted to the ground truth in linear light by least squares), "
        "and at the ground truth's mean grey (`psnr_gt_mean`, as `lumos3d eval` reports it). One scale "
        "per scene is the part a dark photo cannot reveal: how bright the reference was exposed. "
        "Written by `benchmarks/exposure_gap.py`; buu is shown for reference, never used to choose anything.",
        table,
    )  # fmt: skip
    write_section("exposure-gap", text, MODEL_CARD)


if __name__ == "__main__":
    main()
