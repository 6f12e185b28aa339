"""The ceiling of each part of the appearance operator (model/appearance/): each operator family
fitted to the ground truth by gradient descent, then scored at full resolution — the best the
illumination head could do if it predicted the parameters perfectly.

Rows: the blind auto-gamma curve (no fit); one gain per channel in linear light, per scene and
(the issue's 27.5 dB measurement on buu) per view; the per-channel
curve + 3x3 colour matrix; the same plus the per-view local gain grid (1 channel, then 3).
Data: the 20 held-out SICE brackets (data/brackets.py; one pair is a one-view scene) and, for
reference only (never for selection), LOM buu's transforms_test.json frames (one scene of three
views: one operator for the three, one local grid per view).

    .venv/bin/python benchmarks/appearance_oracle.py            # prints the table, rewrites the model-card section
    .venv/bin/python benchmarks/appearance_oracle.py --limit 3  # a quick look at 3 pairs per set

Fits run on images resized to FIT_SIZE on the longer side (speed); scores use the full images.
"""

from __future__ import annotations

import argparse
import logging
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import SHARED_DATA, markdown_table, table_section, write_section  # noqa: E402

from lumos3d_cli.data.brackets import VALIDATION_BRACKETS, bracket_pairs, read_srgb  # noqa: E402
from lumos3d_cli.data.lom import read_lom_scene  # noqa: E402
from lumos3d_cli.eval.metrics import auto_gamma, psnr, ssim  # noqa: E402
from lumos3d_cli.io.colour import srgb_to_linear  # noqa: E402
from lumos3d_cli.model.appearance.curve import CURVE_KNOTS, MAX_GAIN, raw_for_slopes  # noqa: E402
from lumos3d_cli.model.appearance.operator import AppearanceOperator  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MODEL_CARD = REPO / "docs" / "model-card.md"
SHARED = SHARED_DATA
FIT_SIZE = 128
FIT_STEPS = 200
LEARNING_RATE = 0.05

logger = logging.getLogger("appearance_oracle")


def _resize(images: torch.Tensor, longer_side: int) -> torch.Tensor:
    """[V, 3, H, W] -> longer side `longer_side` (area-like antialiased bilinear)."""
    height, width = images.shape[-2:]
    factor = longer_side / max(height, width)
    if factor >= 1:
        return images
    size = (max(1, round(height * factor)), max(1, round(width * factor)))
    return F.interpolate(images, size=size, mode="bilinear", antialias=True, align_corners=False).clamp(0, 1)


def _least_squares_gains(degraded: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """[V, 3, H, W] sRGB pairs -> [3] per-channel gains minimising the squared error in linear light."""
    x, y = srgb_to_linear(degraded.double()), srgb_to_linear(target.double())
    gains = (x * y).sum(dim=(0, 2, 3)) / (x * x).sum(dim=(0, 2, 3)).clamp_min(1e-12)
    return gains.float().clamp(1 / MAX_GAIN * 1.01, MAX_GAIN * 0.99)


def fit_operator(degraded: torch.Tensor, target: torch.Tensor, family: str) -> AppearanceOperator:
    """Fit one scene's operator (B = 1) of `family` ("gain", "curve+matrix", "curve+matrix+local1",
    "curve+matrix+local3") to sRGB images [V, 3, H, W] by Adam on the sRGB squared error."""
    small_degraded, small_target = _resize(degraded, FIT_SIZE)[None], _resize(target, FIT_SIZE)[None]
    views = degraded.shape[0]
    start = raw_for_slopes(_least_squares_gains(degraded, target))  # [3]
    if family == "gain":
        log_gain = torch.log(_least_squares_gains(degraded, target)).requires_grad_(True)
        variables = [log_gain]

        def build() -> AppearanceOperator:
            slopes = torch.exp(log_gain).clamp(1 / MAX_GAIN, MAX_GAIN)
            return AppearanceOperator(slopes.view(1, 3, 1).expand(1, 3, CURVE_KNOTS - 1), torch.eye(3)[None])
    else:
        curve_raw = start.view(1, 3, 1).repeat(1, 1, CURVE_KNOTS - 1).requires_grad_(True)
        matrix_raw = torch.zeros(1, 3, 3, requires_grad=True)
        variables = [curve_raw, matrix_raw]
        local_raw = None
        if family.startswith("curve+matrix+local"):
            local_raw = torch.zeros(1, views, int(family[-1]), 8, 8, requires_grad=True)
            variables.append(local_raw)

        def build() -> AppearanceOperator:
            return AppearanceOperator.from_raw(curve_raw, matrix_raw, local_raw)

    optimiser = torch.optim.Adam(variables, lr=LEARNING_RATE)
    for _ in range(FIT_STEPS):
        optimiser.zero_grad()
        loss = F.mse_loss(build().apply(small_degraded), small_target)
        loss.backward()
        optimiser.step()
    with torch.no_grad():
        return build().detach()


Method = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
FAMILIES = ("gain", "curve+matrix", "curve+matrix+local1", "curve+matrix+local3")
LABELS = {
    "auto-gamma": "auto-gamma (blind, no fit)",
    "gain": "per-channel gain, linear light, one per scene (fitted)",
    "gain per view": "per-channel gain, linear light, one per view (fitted)",
    "curve+matrix": "curve (16 segments) + 3x3 matrix (fitted)",
    "curve+matrix+local1": "+ local 8x8 gain grid, 1 channel (fitted)",
    "curve+matrix+local3": "+ local 8x8 gain grid, 3 channels (fitted)",
}


def _methods() -> dict[str, Method]:
    methods: dict[str, Method] = {"auto-gamma": lambda degraded, target: auto_gamma(degraded)}
    methods["gain per view"] = lambda degraded, target: torch.cat(
        [fit_operator(degraded[v : v + 1], target[v : v + 1], "gain").apply(degraded[None, v : v + 1])[0] for v in range(len(degraded))]
    )
    for family in FAMILIES:
        methods[family] = lambda degraded, target, family=family: fit_operator(degraded, target, family).apply(degraded[None])[0]
    return {name: methods[name] for name in LABELS}


def _score(scenes: list[tuple[torch.Tensor, torch.Tensor]], methods: dict[str, Method]) -> dict[str, tuple[float, float]]:
    """scenes [(degraded, target) [V, 3, H, W]] -> {method: (mean PSNR, mean SSIM)} over all views."""
    results = {}
    for name, method in methods.items():
        if name == "gain per view" and all(len(degraded) == 1 for degraded, _ in scenes):
            results[name] = results["gain"]  # one view: the same fit
            continue
        started = time.perf_counter()
        psnrs, ssims = [], []
        for degraded, target in scenes:
            restored = method(degraded, target).clamp(0, 1)
            psnrs += psnr(restored, target).tolist()
            ssims += ssim(restored, target).tolist()
        results[name] = (statistics.mean(psnrs), statistics.mean(ssims))
        logger.info("%s: %.2f dB / %.3f (%.0f s)", name, *results[name], time.perf_counter() - started)
    return results


def _bracket_scenes(mode: str, limit: int | None) -> list[tuple[torch.Tensor, torch.Tensor]]:
    pairs = bracket_pairs(SHARED / "brackets", mode, "validation")[:limit]
    return [(read_srgb(p.input_path)[None], read_srgb(p.target_path)[None]) for p in pairs]


def _buu_scene(mode: str) -> list[tuple[torch.Tensor, torch.Tensor]]:
    scene = read_lom_scene(SHARED / "lom" / "buu", mode)
    degraded = torch.stack([read_srgb(scene.degraded[frame]) for frame in scene.test])
    target = torch.stack([read_srgb(scene.reference[frame]) for frame in scene.test])
    return [(degraded, target)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--limit", type=int, default=None, help="at most this many bracket pairs per mode (quick look; no doc update)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    torch.manual_seed(0)
    torch.set_num_threads(1)  # many small tensors: threads only contend (and this machine is shared)
    methods = _methods()
    sets = {}
    for mode in ("low-light", "over-exposure"):
        scenes = _bracket_scenes(mode, args.limit)
        logger.info("brackets, %s: %d held-out pairs", mode, len(scenes))
        sets[f"brackets {mode} ({len(scenes)} pairs)"] = _score(scenes, methods)
    for mode in ("low-light", "over-exposure"):
        logger.info("LOM buu, %s (reference only)", mode)
        sets[f"buu {mode} (reference)"] = _score(_buu_scene(mode), methods)
    header = ["operator"] + list(sets)
    rows = [[LABELS[name]] + [f"{sets[s][name][0]:.2f} / {sets[s][name][1]:.3f}" for s in sets] for name in methods]
    table = markdown_table(header, rows)
    print(table)
    if args.limit is not None:
        return
    text = table_section(
        "### Appearance operator: the ceiling of each part",
        "PSNR (dB) / SSIM of each operator family of `model/appearance/` **fitted to the ground truth** "
        f"(Adam, {FIT_STEPS} steps on the sRGB squared error at {FIT_SIZE} px, scored at full resolution): "
        "what the illumination head could reach if it predicted the parameters perfectly. Brackets: the 20 "
        f"held-out SICE brackets ({', '.join(VALIDATION_BRACKETS[:3])}, ...; `data/brackets.py`), every "
        "input/target pair of the pairing rule, one pair = one one-view scene. buu: the three "
        "`transforms_test.json` frames as one scene (one operator; one local grid per view); shown for "
        "reference, never used to choose anything. Auto-gamma is the blind baseline "
        "(`eval.metrics.auto_gamma`). Written by `benchmarks/appearance_oracle.py`.",
        table,
    )  # fmt: skip
    write_section("appearance-oracle", text, MODEL_CARD)


if __name__ == "__main__":
    main()
