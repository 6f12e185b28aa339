"""Choosing the exposure prior's strength (`model.appearance.exposure_prior`): each bundled
model's illumination head restores a scene's photos in 2D (the operator, with the prior computed
on the network images as `restore` does, applied at full resolution), scored at every strength
from 0 (the head alone) to 1 (the key alone).

The strength is chosen on the SICE brackets' training split (the pairs the heads were trained
on: the prior corrects the head's brightness error, which is there too) and confirmed on the 20
held-out brackets; LOM buu is shown for reference only, never used to choose anything. The key
(mean sRGB 0.45) is fixed beforehand: the level the pairing rule calls well exposed.

    .venv/bin/python benchmarks/exposure_prior.py            # prints the table, rewrites the model-card section
    .venv/bin/python benchmarks/exposure_prior.py --limit 3  # a quick look at 3 pairs per split (no doc update)
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
from lumos3d_cli.eval.metrics import psnr, ssim  # noqa: E402
from lumos3d_cli.model.appearance.exposure_prior import EXPOSURE_KEY, EXPOSURE_PRIOR_STRENGTH, apply_exposure_prior  # noqa: E402
from lumos3d_cli.model.appearance.photo_restoration import restore_photos  # noqa: E402
from lumos3d_cli.model.bundled_models import resolve_checkpoint  # noqa: E402
from lumos3d_cli.model.loading import load_model  # noqa: E402
from lumos3d_cli.model.lumos3d import Lumos3D  # noqa: E402
from lumos3d_cli.model.preprocess import prepare_images  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MODEL_CARD = REPO / "docs" / "model-card.md"
SHARED = SHARED_DATA
STRENGTHS = (0.0, 0.25, 0.5, 0.75, 1.0)

logger = logging.getLogger("exposure_prior")


def score_scene(model: Lumos3D, photos: torch.Tensor, scored: list[int], targets: torch.Tensor) -> torch.Tensor:
    """photos [V, 3, H, W] sRGB (the operator and the prior see all of them), scored: the views
    with targets [S, 3, H, W] -> [len(STRENGTHS), S, 2]: PSNR and SSIM at each strength."""
    network = prepare_images(photos, model.architecture.image_size, model.architecture.patch_size).images[None]
    with torch.no_grad():
        operator = model.predict_appearance(network)
        scores = []
        for strength in STRENGTHS:
            scene = apply_exposure_prior(operator, network, strength).scene(0)
            restored = restore_photos(photos[scored], scene.views(torch.tensor(scored)))
            scores.append(torch.stack([psnr(restored, targets), ssim(restored, targets).float()], dim=1))
    return torch.stack(scores)


def _cell(scores: list[torch.Tensor], strength_index: int) -> str:
    values = torch.cat([score[strength_index] for score in scores]).mean(dim=0)
    return f"{values[0]:.2f} / {values[1]:.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--limit", type=int, default=None, help="at most this many bracket pairs per split (no doc update)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    torch.set_num_threads(1)  # small one-view scenes: threads only contend
    columns, results = [], []
    for mode in ("low-light", "over-exposure"):
        model = load_model(resolve_checkpoint(None, mode)).eval()
        for split, label in (("train", "training split"), ("validation", "held-out")):
            pairs = bracket_pairs(SHARED / "brackets", mode, split)[: args.limit]
            results.append([score_scene(model, read_srgb(pair.input_path)[None], [0], read_srgb(pair.target_path)[None])
                            for pair in pairs])
            columns.append(f"SICE {label}, {mode} ({len(pairs)} pairs)")
            logger.info("%s: %s", columns[-1], [_cell(results[-1], i) for i in range(len(STRENGTHS))])
        scene = read_lom_scene(SHARED / "lom" / "buu", mode)
        photos = torch.stack([read_srgb(scene.degraded[frame]) for frame in scene.frames])
        targets = torch.stack([read_srgb(scene.reference[frame]) for frame in scene.test])
        results.append([score_scene(model, photos, [scene.frames.index(frame) for frame in scene.test], targets)])
        columns.append(f"LOM buu, {mode} (reference)")
    rows = []
    for index, strength in enumerate(STRENGTHS):
        label = f"{strength:g}" + (" (head alone)" if strength == 0 else " (key alone)" if strength == 1 else "")
        defaults = [mode for mode, value in EXPOSURE_PRIOR_STRENGTH.items() if value == strength]
        label += f" **default ({', '.join(defaults)})**" if defaults else ""
        rows.append([label, *(_cell(scores, index) for scores in results)])
    table = markdown_table(["prior strength", *columns], rows)
    print(table)
    if args.limit is not None:
        return
    text = table_section(
        "### The exposure prior: choosing its strength",
        "PSNR (dB) / SSIM of each bundled head's 2D restoration (the operator at full resolution, no 3D) "
        f"with the exposure prior (`model/appearance/exposure_prior.py`) pulling each scene's mean sRGB towards {EXPOSURE_KEY} "
        "by the given strength (0: the head's own exposure; 1: the key's). The strength is chosen on the "
        "brackets' training split and confirmed on the held-out brackets; buu is shown for reference, never "
        "used to choose anything. Written by `benchmarks/exposure_prior.py`.",
        table,
    )  # fmt: skip
    write_section("exposure-prior", text, MODEL_CARD)


if __name__ == "__main__":
    main()
