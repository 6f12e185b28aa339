"""Issue 15's appearance ablation at the tiny scale, scored without LOM: the low-light
illumination head trained alone (configs/operator-head-low-light.yaml) with and without the SICE
brackets, with and without the degraded multi-view scenes, with and without the per-view local
gain grid; and the operator against the colour-regression model it started from.

Scores, none of them on buu:
- held-out brackets: every low-light pair (51) of the 20 held-out SICE brackets at the network
  size (what validation reports);
- Strecha 2D: the six ground-truth-camera scenes (never trained on), every view darkened with the
  training's camera-pipeline model at a fixed seed per scene, restored by the operator predicted
  from up to 8 of them at long side 768; PSNR / SSIM / sharpness against the clean photos;
- Strecha 3D: fountain-P11 darkened the same way and restored by `lumos3d restore --poses` (its
  ground-truth cameras) with each model, restored views against the clean photos: this is the only
  row where the regression model can take part.

    .venv/bin/python benchmarks/appearance_ablation.py --train   # train missing variants, score
    .venv/bin/python benchmarks/appearance_ablation.py           # score the runs in runs/

Each variant trains `--steps` head-only steps (0.1-2 s a step on 2 CPU cores, depending on what
else runs). The table is the "appearance-ablation" section of docs/model-card.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cli_runs import REPO, run_lumos3d, run_lumos3d_json  # noqa: E402
from report import machine_description, markdown_table, write_section  # noqa: E402

from lumos3d_cli.data.brackets import BracketDataset  # noqa: E402
from lumos3d_cli.data.degradations import degrade  # noqa: E402
from lumos3d_cli.eval.metrics import auto_gamma, psnr, sharpness, ssim  # noqa: E402
from lumos3d_cli.model.appearance.photo_restoration import restore_photos  # noqa: E402
from lumos3d_cli.model.bundled_models import resolve_checkpoint  # noqa: E402
from lumos3d_cli.model.loading import load_model  # noqa: E402
from lumos3d_cli.train.config import load_config  # noqa: E402

CONFIG = "configs/operator-head-low-light.yaml"
MODEL_CARD = REPO / "docs" / "model-card.md"
STRECHA = REPO.parent / "shared" / "data" / "gt_cameras"
LONG_SIDE = 512
VIEWS = 8  # per scene, evenly spaced: the network's input and the views scored


@dataclass(frozen=True)
class Variant:
    label: str
    run: str
    overrides: tuple[str, ...] = ()


SCENES = ("multiview=true", "multiview_loss=appearance")  # add the degraded multi-view scenes
VARIANTS = (
    Variant("operator: brackets, local grid (shipped)", "runs/operator-head-low-light"),
    Variant("operator: brackets + degraded scenes, local grid", "runs/ablation-appearance-mixed", SCENES),
    Variant("operator: brackets + degraded scenes, no local grid", "runs/ablation-appearance-nolocal",
            (*SCENES, "local_correction_channels=0")),
    Variant("operator: degraded scenes only, local grid", "runs/ablation-appearance-scenes", (*SCENES, "brackets.root=null")),
)


def _train(variant: Variant, steps: int) -> None:
    print(f"training {variant.run} ({variant.label})", flush=True)
    run_lumos3d(["train", CONFIG, f"output={variant.run}", f"optim.steps={steps}", f"checkpoint_every={steps}",
                 "validate_every=0", *variant.overrides])


def _read(path: Path) -> torch.Tensor:
    """sRGB [3, H, W] float32 at long side LONG_SIDE."""
    pixels = cv2.imread(str(path))[..., ::-1]
    scale = LONG_SIDE / max(pixels.shape[:2])
    size = (round(pixels.shape[1] * scale), round(pixels.shape[0] * scale))
    pixels = cv2.resize(pixels, size, interpolation=cv2.INTER_AREA)
    return torch.from_numpy(pixels.astype(np.float32) / 255).permute(2, 0, 1)


def darkened_strecha(settings, views: int | None = VIEWS) -> dict[str, tuple[torch.Tensor, torch.Tensor, list[str]]]:
    """scene -> (darkened [V, 3, H, W], clean [V, 3, H, W], file names), V <= `views` evenly
    spaced (None: all): the training's degradation, one draw per scene, seeded by the scene's
    position."""
    scenes = {}
    for index, folder in enumerate(sorted(p for p in STRECHA.iterdir() if p.is_dir())):
        paths = sorted((folder / "images").iterdir())
        if views is not None:
            paths = [paths[i] for i in np.linspace(0, len(paths) - 1, min(views, len(paths))).round().astype(int)]
        clean = torch.stack([_read(p) for p in paths])
        dark, _ = degrade(clean[None], settings, torch.Generator().manual_seed(1000 + index))
        scenes[folder.name] = (dark[0], clean, [p.name for p in paths])
    return scenes


def bracket_scores(model, root: str) -> tuple[float, float]:
    """Mean PSNR / SSIM of every low-light pair of the 20 held-out brackets at the network size."""
    dataset = BracketDataset(root, "low-light", "validation", (224, 168), (1.0, 1.0), flip=False, seed=0)
    psnrs, ssims = [], []
    with torch.no_grad():
        for index in range(len(dataset)):
            sample = dataset[index]
            inputs, target = sample["images"][None], sample["targets"][None]
            restored = model.predict_appearance(inputs).apply(inputs).clamp(0, 1)
            psnrs.append(float(psnr(restored[0, 0], target[0, 0])))
            ssims.append(float(ssim(restored[0, 0], target[0, 0])))
    return float(np.mean(psnrs)), float(np.mean(ssims))


def strecha_2d_scores(model, scenes) -> tuple[float, float, float]:
    """Mean PSNR / SSIM / sharpness of every view the operator restores, over the scenes."""
    rows = []
    with torch.no_grad():
        for dark, clean, _ in scenes.values():
            network = F.interpolate(dark, size=(168, 224), mode="area")[None]
            restored = restore_photos(dark, model.predict_appearance(network).scene(0))
            rows.append(torch.stack([psnr(restored, clean), ssim(restored, clean), sharpness(restored, clean)], dim=1))
    return tuple(float(v) for v in torch.cat(rows).mean(dim=0))


def gamma_2d_scores(scenes) -> tuple[float, float, float]:
    rows = []
    for dark, clean, _ in scenes.values():
        corrected = auto_gamma(dark)
        rows.append(torch.stack([psnr(corrected, clean), ssim(corrected, clean), sharpness(corrected, clean)], dim=1))
    return tuple(float(v) for v in torch.cat(rows).mean(dim=0))


def strecha_3d_scores(checkpoint: Path, scene, folder: Path) -> tuple[float, float, float, float]:
    """(PSNR, SSIM, sharpness, seconds) of `lumos3d restore --poses` on darkened fountain-P11 (all
    11 views)."""
    dark, clean, names = scene
    inputs, references = folder / "dark", folder / "clean"
    if not inputs.exists():
        inputs.mkdir(parents=True)
        references.mkdir()
        for image, reference, name in zip(dark, clean, names):
            stem = Path(name).stem
            cv2.imwrite(str(inputs / f"{stem}.png"), (image.permute(1, 2, 0).numpy()[..., ::-1] * 255).round().astype(np.uint8))
            cv2.imwrite(str(references / f"{stem}.png"), (reference.permute(1, 2, 0).numpy()[..., ::-1] * 255).round().astype(np.uint8))
    output = folder / checkpoint.stem / "scene.ply"
    summary, seconds = run_lumos3d_json(["restore", str(inputs), "-o", str(output), "--checkpoint", str(checkpoint),
                                         "--poses", str(STRECHA / "fountain-P11" / "sparse" / "0"), "--reference", str(references)])
    restored = torch.stack([torch.from_numpy(cv2.imread(str(output.parent / "restored" / f"{Path(n).stem}.png"))[..., ::-1]
                                             .astype(np.float32) / 255).permute(2, 0, 1) for n in names])
    mean = summary["metrics"]["mean"]
    return mean["psnr"], mean["ssim"], float(sharpness(restored, clean).mean()), seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", action="store_true", help="train the variants whose final weights are missing")
    parser.add_argument("--steps", type=int, default=500, help="head-only steps per variant (the shipped config's 500)")
    args = parser.parse_args()
    config = load_config(REPO / CONFIG)
    for variant in VARIANTS:
        if args.train and not (REPO / variant.run / "final.safetensors").exists():
            _train(variant, args.steps)
    scenes = darkened_strecha(config.degrade)
    rows = []
    gamma = gamma_2d_scores(scenes)
    rows.append(["auto-gamma curve (no learning)", "–", "–", f"{gamma[0]:.2f}", f"{gamma[1]:.3f}", f"{gamma[2]:.2f}", "–", "–"])
    with tempfile.TemporaryDirectory() as scratch:
        fountain = darkened_strecha(config.degrade, views=None)["fountain-P11"]
        regression = resolve_checkpoint(None, "low-light")
        p, s, sharp, _ = strecha_3d_scores(regression, fountain, Path(scratch))
        rows.append(["regression (bundled low-light model, its colours regressed)", "–", "–", "–", "–", "–",
                     f"{p:.2f} / {s:.3f}", f"{sharp:.2f}"])
        for variant in VARIANTS:
            weights = REPO / variant.run / "final.safetensors"
            if not weights.exists():
                print(f"skipping {variant.run}: no final.safetensors (run with --train)", flush=True)
                continue
            model = load_model(weights).eval()
            bracket_psnr, bracket_ssim = bracket_scores(model, config.brackets.root)
            two_d = strecha_2d_scores(model, scenes)
            p, s, sharp, _ = strecha_3d_scores(weights, fountain, Path(scratch))
            rows.append([variant.label, f"{bracket_psnr:.2f}", f"{bracket_ssim:.3f}", f"{two_d[0]:.2f}", f"{two_d[1]:.3f}",
                         f"{two_d[2]:.2f}", f"{p:.2f} / {s:.3f}", f"{sharp:.2f}"])
            print(json.dumps({"variant": variant.label, "row": rows[-1]}), flush=True)
    header = ["variant", "held-out brackets PSNR", "SSIM", "Strecha 2D PSNR", "SSIM", "sharpness",
              "fountain-P11 restore PSNR / SSIM", "sharpness"]
    text = (f"Script: `benchmarks/appearance_ablation.py --steps {args.steps}` ({machine_description()}). Head-only "
            f"training from the bundled low-light model, {args.steps} steps each, seed 1, config "
            f"`{CONFIG}` with the row's change. Darkening: the config's camera-pipeline model (exposure "
            f"{config.degrade.exposure}, gamma {config.degrade.gamma}, noise, colour cast, 8-bit, JPEG), one seeded draw per "
            f"scene. Strecha images at long side {LONG_SIDE}. Sharpness: high-frequency energy over the clean photo's "
            "(1 = as sharp). No LOM data is used.\n\n" + markdown_table(header, rows))
    write_section("appearance-ablation", text, MODEL_CARD)
    print(text)


if __name__ == "__main__":
    main()
