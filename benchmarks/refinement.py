"""Test-time refinement on buu's demo (examples/lowlight-buu): loss and PSNR against the number of
steps, and seconds per step.

The scene is built as `lumos3d restore` builds it (bundled model, preset, structure-from-motion),
except that one view (`--holdout`) is left out of the fused scene and of the refinement: it is
a novel view of what the others made. The refinement targets are the restored input views: the
model's per-view restoration (the operator applied to the photos for an operator model, the
network's per-pixel colours, upsampled to the photos' size, for a colour-regression model).
Scores: PSNR of the renders at the photos' resolution against those targets (the fit) and,
when ../shared/data/lom/buu is present, against buu's normal-light photos of the same views
(`high/`, downsized to the demo's size): the fitted views, and the held-out view.

Each step count is its own run from the forward pass, with early stop off; the last row runs the
largest count with the default early stop. The 0-step run times the setup (working views, the SH
degree choice); s/step is the rest over the steps. The refinement is `refine.RefineSettings`'
defaults at `--max-side`: a study of the optimiser and its step cost, not what a preset's
`--refine-steps N` gives (the presets fit at their own side, with their learning-rate decay,
densification and filled views; `benchmarks/presets.py` measures those).

    .venv/bin/python benchmarks/refinement.py                      # steps 0 25 50 100 200
    .venv/bin/python benchmarks/refinement.py --steps 0 10 --max-side 128

The numba kernels and torch both run OpenMP thread pools; with OMP_WAIT_POLICY unset their idle
threads spin, which on a machine busy with other work made a step 2-4x slower (no difference on
an idle one): the table's header says which policy the run had.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from dataclasses import replace
from pathlib import Path

import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import SHARED_DATA, machine_description, markdown_table  # noqa: E402

from lumos3d_cli.eval.metrics import psnr  # noqa: E402
from lumos3d_cli.io.gaussians import SH_C0, sh_coefficient_count  # noqa: E402
from lumos3d_cli.io.image_files import list_images  # noqa: E402
from lumos3d_cli.io.images import load_images  # noqa: E402
from lumos3d_cli.model.appearance.photo_restoration import restore_photos  # noqa: E402
from lumos3d_cli.model.bundled_models import resolve_checkpoint  # noqa: E402
from lumos3d_cli.model.gaussian_adapter import SH_START  # noqa: E402
from lumos3d_cli.model.lumos3d import Lumos3D  # noqa: E402
from lumos3d_cli.pipeline.model_loading import load_restoration_model  # noqa: E402
from lumos3d_cli.pipeline.network_pass import run_network  # noqa: E402
from lumos3d_cli.pipeline.presets import get_restore_preset  # noqa: E402
from lumos3d_cli.pipeline.scene_stages import build_scene  # noqa: E402
from lumos3d_cli.refine.photometric import photometric_loss  # noqa: E402
from lumos3d_cli.refine.refinement import refine_gaussians  # noqa: E402
from lumos3d_cli.refine.settings import RefineSettings  # noqa: E402
from lumos3d_cli.render.render import render  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "examples" / "lowlight-buu"
BUU_HIGH = SHARED_DATA / "lom" / "buu" / "high"


def restored_views(model: Lumos3D, photos: torch.Tensor, preset) -> torch.Tensor:
    """The model's own restoration of photos [V, 3, H, W] (all through the network at once):
    [V, 3, H, W] in [0, 1]."""
    network = run_network(model, photos, preset)
    prediction = network.prediction
    if prediction.appearance is not None:
        return restore_photos(photos, prediction.appearance.scene(0))
    count = sh_coefficient_count(model.architecture.sh_degree)
    params = prediction.params[0]  # [V, h, w, C-1]; colour-major SH, DC first
    colours = 0.5 + SH_C0 * torch.stack([params[..., SH_START + c * count] for c in range(3)], dim=1)
    return F.interpolate(colours, size=photos.shape[-2:], mode="bilinear", align_corners=False).clamp(0, 1)


def normal_light(names: list[str], size: tuple[int, int]) -> torch.Tensor | None:
    """buu's high/ photos of `names` at size (height, width), or None without the shared data."""
    paths = [BUU_HIGH / f"{Path(name).stem}.JPG" for name in names]
    if not all(path.is_file() for path in paths):
        return None
    return F.interpolate(load_images(paths).images, size=size, mode="area")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, nargs="+", default=[0, 25, 50, 100, 200])
    parser.add_argument("--holdout", default="10.jpg", help="the view left out of the scene and the refinement")
    parser.add_argument("--preset", default="balanced")
    parser.add_argument("--mode", default="low-light")
    parser.add_argument("--max-side", type=int, default=RefineSettings.max_side)
    arguments = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)

    paths = list_images(DEMO)
    names = [path.name for path in paths]
    photos = load_images(paths).images
    model = load_restoration_model(resolve_checkpoint(None, arguments.mode), "cpu")
    preset = get_restore_preset(arguments.preset)
    held = names.index(arguments.holdout)
    built = build_scene(photos, names, model, preset, required_views=[held],
                        fuse_views=[index != held for index in range(len(names))])
    if built.selected != list(range(len(names))):
        raise SystemExit("the network must see every demo view (its restoration is the target)")
    cameras = built.geometry.cameras
    order = [names.index(name) for name in cameras.names]
    targets = restored_views(model, photos, preset)[order]
    references = normal_light(cameras.names, tuple(photos.shape[-2:]))
    fitted = [i for i, name in enumerate(cameras.names) if name != arguments.holdout]
    holdout = [cameras.names.index(arguments.holdout)]

    base = RefineSettings(max_side=arguments.max_side)
    counts = sorted({0, *arguments.steps})  # 0 steps: the setup (working views, SH degree) alone
    runs = [(steps, replace(base, steps=steps, patience=10**9)) for steps in counts]
    runs.append((max(arguments.steps), replace(base, steps=max(arguments.steps))))
    rows = []
    setup_seconds = 0.0
    for asked, settings in runs:
        result = refine_gaussians(built.gaussians, cameras[fitted], targets[fitted], settings)
        if asked == 0:
            setup_seconds = result.seconds
        per_step = (result.seconds - setup_seconds) / result.steps_run if result.steps_run else None
        with torch.no_grad():
            renders = torch.cat([render(result.gaussians, cameras[[v]]).images for v in range(len(cameras))]).clamp(0, 1)
        row = [asked, result.steps_run, "yes" if settings.patience < 10**9 else "off",
               f"{result.seconds:.1f}", "-" if per_step is None else f"{per_step:.2f}",
               f"{photometric_loss(renders[fitted], targets[fitted], settings.ssim_weight).item():.4f}",
               f"{psnr(renders[fitted], targets[fitted]).mean().item():.2f}"]
        if references is not None:
            row += [f"{psnr(renders[fitted], references[fitted]).mean().item():.2f}",
                    f"{psnr(renders[holdout], references[holdout]).mean().item():.2f}"]
        rows.append(row)
        print(f"steps {asked}: {row}", file=sys.stderr, flush=True)

    header = ["steps", "run", "early stop", "s", "s/step (after setup)", "loss (fitted)", "PSNR fitted vs targets"]
    if references is not None:
        header += ["PSNR fitted vs high", f"PSNR held-out {arguments.holdout} vs high"]
    print(f"buu demo: {len(fitted)} fitted views + 1 held out, {len(built.gaussians):,} Gaussians, "
          f"{photos.shape[-1]}x{photos.shape[-2]} photos, refined at max side {arguments.max_side}, "
          f"preset {preset.name}, {arguments.mode} model; {machine_description()}; "
          f"OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY', 'unset')}\n")
    print(markdown_table(header, rows))


if __name__ == "__main__":
    main()
