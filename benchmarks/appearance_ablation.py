"""Issue 15's appearance ablation at the tiny scale, scored without LOM, for one mode: the
illumination head trained alone (configs/operator-head-<mode>.yaml) with and without the SICE
brackets, with and without the degraded multi-view scenes, with and without the per-view local
gain grid; the colour-regression model the operator started from; the bundled model; and (low
light) the mixed-batch stage of configs/operator-low-light.yaml, which this script scores but does
not train (about 4 s a step on 2 CPU cores: run `lumos3d train configs/operator-low-light.yaml`).

Scores, none of them on buu:
- held-out brackets: every pair of the mode (low light 51, over-exposure 36) of the 20 held-out
  SICE brackets at the network size (what validation reports), and every already well-exposed
  pair (how much a model disturbs a photo that needs nothing). The operators restore the pair's
  input with their predicted operator; the regression model renders its one-view Gaussians at
  its own camera;
- Strecha 2D: the six ground-truth-camera scenes (never trained on), every view degraded with the
  training's camera-pipeline model at a fixed seed per scene, restored by the operator predicted
  from up to 8 of them; PSNR / SSIM / sharpness against the clean photos;
- Strecha 3D: fountain-P11 degraded the same way and restored by `lumos3d restore --poses` (its
  ground-truth cameras) with each model, restored views against the clean photos.

    .venv/bin/python benchmarks/appearance_ablation.py --train                       # low light
    .venv/bin/python benchmarks/appearance_ablation.py --train --mode over-exposure

Each variant trains `--steps` head-only steps (0.1-2 s a step on 2 CPU cores, depending on what
else runs). The tables are the "appearance-ablation" and "appearance-ablation-over-exposure"
sections of docs/model-card.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cli_runs import REPO, run_lumos3d, run_lumos3d_json  # noqa: E402
from report import SHARED_DATA, machine_description, markdown_table, write_section  # noqa: E402

from lumos3d_cli.data.degradations import degrade  # noqa: E402
from lumos3d_cli.eval.metrics import auto_gamma, psnr, sharpness, ssim  # noqa: E402
from lumos3d_cli.model.appearance.conversion import with_appearance  # noqa: E402
from lumos3d_cli.model.appearance.photo_restoration import restore_photos  # noqa: E402
from lumos3d_cli.model.bundled_models import resolve_checkpoint  # noqa: E402
from lumos3d_cli.model.checkpoints import save_checkpoint  # noqa: E402
from lumos3d_cli.model.loading import load_model  # noqa: E402
from lumos3d_cli.train.bracket_samples import BracketSamples  # noqa: E402
from lumos3d_cli.train.config import load_config  # noqa: E402
from lumos3d_cli.train.validation import render_views  # noqa: E402

MODEL_CARD = REPO / "docs" / "model-card.md"
STRECHA = SHARED_DATA / "gt_cameras"
LONG_SIDE = 512
VIEWS = 8  # per scene, evenly spaced: the network's input and the views scored
NETWORK_SIZE = (224, 168)


@dataclass(frozen=True)
class Variant:
    """A model of the table: `run`/`weights` (None: the bundled model), trained by this script
    with the mode's head config and `overrides` when `trained_here`."""

    label: str
    run: str | None
    overrides: tuple[str, ...] = ()
    weights: str = "final.safetensors"
    trained_here: bool = True

    def checkpoint(self, mode: str) -> Path:
        return resolve_checkpoint(None, mode) if self.run is None else REPO / self.run / self.weights


SCENES = ("multiview=true", "multiview_loss=appearance")  # add the degraded multi-view scenes
NO_LOCAL_GRID = ("local_correction_channels=0",)
BUNDLED = Variant("bundled model (its head: the head config's 1,000 steps)", None, trained_here=False)
VARIANTS = {
    "low-light": (
        BUNDLED,
        Variant("operator: brackets, local grid (the head config)", "runs/ablation-appearance-brackets"),
        Variant("operator: brackets, no local grid", "runs/ablation-appearance-brackets-nolocal", NO_LOCAL_GRID),
        Variant("operator: brackets + degraded scenes, local grid", "runs/ablation-appearance-mixed", SCENES),
        Variant("operator: brackets + degraded scenes, no local grid", "runs/ablation-appearance-nolocal",
                (*SCENES, *NO_LOCAL_GRID)),
        Variant("operator: degraded scenes only, local grid", "runs/ablation-appearance-scenes", (*SCENES, "brackets.root=null")),
        # its selection is step 0 (the bundled model): this row shows what 200 of its steps did
        Variant("bundled model + 200 steps of mixed batches, whole network (configs/operator-low-light.yaml)",
                "runs/operator-low-light", weights="checkpoints/step_00000200", trained_here=False),
    ),
    "over-exposure": (
        BUNDLED,
        Variant("operator: brackets, local grid (the head config)", "runs/ablation-overexp-brackets"),
        Variant("operator: brackets, no local grid", "runs/ablation-overexp-brackets-nolocal", NO_LOCAL_GRID),
        Variant("operator: brackets + degraded scenes, local grid", "runs/ablation-overexp-mixed", SCENES),
    ),
}
SECTIONS = {"low-light": "appearance-ablation", "over-exposure": "appearance-ablation-over-exposure"}


def _head_config(mode: str) -> str:
    return f"configs/operator-head-{mode}.yaml"


def _train(variant: Variant, mode: str, steps: int, student: Path) -> None:
    print(f"training {variant.run} ({variant.label})", flush=True)
    run_lumos3d(["train", _head_config(mode), f"output={variant.run}", f"model={student}", f"optim.steps={steps}",
                 f"checkpoint_every={steps}", "validate_every=0", "select=null", *variant.overrides])


def _read(path: Path) -> torch.Tensor:
    """sRGB [3, H, W] float32 at long side LONG_SIDE."""
    pixels = cv2.imread(str(path))[..., ::-1]
    scale = LONG_SIDE / max(pixels.shape[:2])
    size = (round(pixels.shape[1] * scale), round(pixels.shape[0] * scale))
    pixels = cv2.resize(pixels, size, interpolation=cv2.INTER_AREA)
    return torch.from_numpy(pixels.astype(np.float32) / 255).permute(2, 0, 1)


def degraded_strecha(settings, views: int | None = VIEWS) -> dict[str, tuple[torch.Tensor, torch.Tensor, list[str]]]:
    """scene -> (degraded [V, 3, H, W], clean [V, 3, H, W], file names), V <= `views` evenly
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


def render_one_view(model, inputs: torch.Tensor) -> torch.Tensor:
    """A colour-regression model's "restoration" of one photo: its Gaussians rendered at its own
    predicted camera, at the network size ([1, 1, 3, H, W] in and out)."""
    rendered, _ = render_views(model(inputs), (0.0, 0.0, 0.0))
    return rendered


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


def strecha_3d_scores(checkpoint: Path, scene, folder: Path, mode: str, name: str) -> tuple[float, float, float]:
    """(PSNR, SSIM, sharpness) of `lumos3d restore --poses --mode MODE` on degraded fountain-P11
    (all 11 views); the scene is written under `folder`/`name`."""
    dark, clean, names = scene
    inputs, references = folder / "degraded", folder / "clean"
    if not inputs.exists():
        inputs.mkdir(parents=True)
        references.mkdir()
        for image, reference, name in zip(dark, clean, names):
            stem = Path(name).stem
            cv2.imwrite(str(inputs / f"{stem}.png"), (image.permute(1, 2, 0).numpy()[..., ::-1] * 255).round().astype(np.uint8))
            cv2.imwrite(str(references / f"{stem}.png"), (reference.permute(1, 2, 0).numpy()[..., ::-1] * 255).round().astype(np.uint8))
    output = folder / name / "scene.ply"
    summary, _ = run_lumos3d_json(["restore", str(inputs), "-o", str(output), "--checkpoint", str(checkpoint), "--mode", mode,
                                   "--poses", str(STRECHA / "fountain-P11" / "sparse" / "0"), "--reference", str(references)])
    restored = torch.stack([torch.from_numpy(cv2.imread(str(output.parent / "restored" / f"{Path(n).stem}.png"))[..., ::-1]
                                             .astype(np.float32) / 255).permute(2, 0, 1) for n in names])
    mean = summary["metrics"]["mean"]
    return mean["psnr"], mean["ssim"], float(sharpness(restored, clean).mean())


def _regression_student(mode: str) -> Path:
    """The colour-regression student inside the bundled model of `mode` (the operator network
    holds all its tensors; conversion.with_appearance drops the illumination head): the regression
    row, and what the head-only variants start from (the head configs name the student of
    `make weights`, runs/default-<mode>/final.safetensors, which this saves a retraining)."""
    operator = load_model(resolve_checkpoint(None, mode))
    regression = with_appearance(operator, "regression")
    return save_checkpoint(regression, REPO / "runs" / f"ablation-student-{mode}.safetensors", regression.provenance,
                           overwrite=True)


def _row(label: str, brackets: dict[str, float] | None, two_d, three_d) -> list[str]:
    cells = [label]
    cells += ["–"] * 4 if brackets is None else [
        f"{brackets['bracket_psnr']:.2f}", f"{brackets['bracket_ssim']:.3f}",
        f"{brackets['bracket_well_exposed_psnr']:.2f}", f"{brackets['bracket_well_exposed_ssim']:.3f}"]
    cells += ["–"] * 3 if two_d is None else [f"{two_d[0]:.2f}", f"{two_d[1]:.3f}", f"{two_d[2]:.2f}"]
    cells += ["–", "–"] if three_d is None else [f"{three_d[0]:.2f} / {three_d[1]:.3f}", f"{three_d[2]:.2f}"]
    return cells


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mode", choices=tuple(VARIANTS), default="low-light")
    parser.add_argument("--train", action="store_true", help="train the head-only variants whose final weights are missing")
    parser.add_argument("--steps", type=int, default=500, help="head-only steps per variant (the head configs train 1,000)")
    args = parser.parse_args()
    mode, variants = args.mode, VARIANTS[args.mode]
    config = load_config(REPO / _head_config(mode))
    student = _regression_student(mode)
    brackets = BracketSamples(config.brackets, mode, NETWORK_SIZE, (1.0, 1.0), seed=0)  # what validation scores
    cpu = torch.device("cpu")
    for variant in variants:
        if args.train and variant.trained_here and not variant.checkpoint(mode).exists():
            _train(variant, mode, args.steps, student)
    scenes = degraded_strecha(config.degrade)
    gamma = gamma_2d_scores(scenes)
    rows = [_row("auto-gamma curve (no learning)", None, gamma, None)]
    with tempfile.TemporaryDirectory() as scratch:
        fountain = degraded_strecha(config.degrade, views=None)["fountain-P11"]
        rows.append(_row("regression (the student inside the bundled model, its colours regressed)",
                         brackets.scores(load_model(student).eval(), cpu, render_one_view), None,
                         strecha_3d_scores(student, fountain, Path(scratch), mode, "regression")))
        print(json.dumps({"variant": "regression", "row": rows[-1]}), flush=True)
        for index, variant in enumerate(variants):
            weights = variant.checkpoint(mode)
            if not weights.exists():
                print(f"skipping {variant.label}: no {weights} (train it first)", flush=True)
                continue
            model = load_model(weights).eval()
            rows.append(_row(variant.label, brackets.scores(model, cpu),
                             strecha_2d_scores(model, scenes), strecha_3d_scores(weights, fountain, Path(scratch), mode,
                                                                                f"variant-{index}")))
            print(json.dumps({"variant": variant.label, "row": rows[-1]}), flush=True)
    header = ["variant", "held-out brackets PSNR", "SSIM", "well-exposed held-out PSNR", "SSIM", "Strecha 2D PSNR", "SSIM",
              "sharpness", "fountain-P11 restore PSNR / SSIM", "sharpness"]
    degradation = (f"exposure {config.degrade.exposure}, gamma {config.degrade.gamma}, noise, colour cast, 8-bit, JPEG"
                   if mode == "low-light" else "the over-exposure tone curve at its documented ranges")
    text = (f"Script: `benchmarks/appearance_ablation.py --mode {mode} --steps {args.steps}` ({machine_description()}). "
            f"Head-only rows: a fresh head trained over the {mode} student (the bundled model without its head; "
            f"everything else frozen), {args.steps} steps "
            f"each, seed 1, config `{_head_config(mode)}` with the row's change. Degradation of the Strecha scenes: "
            f"the config's camera-pipeline model ({degradation}), one seeded draw per scene, images at long side "
            f"{LONG_SIDE}. Held-out brackets at {NETWORK_SIZE[0]}x{NETWORK_SIZE[1]}: the mode's pairs and the "
            "already well-exposed ones. Sharpness: high-frequency energy over the clean photo's (1 = as sharp). "
            "No LOM data is used.\n\n" + markdown_table(header, rows))
    write_section(SECTIONS[mode], text, MODEL_CARD)
    print(text)


if __name__ == "__main__":
    main()
