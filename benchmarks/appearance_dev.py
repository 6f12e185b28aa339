"""Issue 35's development benchmark: the restoration scored on every real source the project may
choose constants on, with the blind auto-gamma curve beside each, per mode, and the mean over the
sources (each source weighs the same), which is what constants are chosen on.

Sources (evaluation and choosing constants only; never trained on):
- LOM buu and shrub (`../shared/data/lom`), both modes, both protocols (context, holdout),
  through `lumos3d eval`'s own machinery (pipeline.evaluation.evaluate_lom): the scene
  restored from its photos and rendered at the test frames' cameras;
- LOL eval15 (`../shared/data/lol_eval15/{low,high}`, 15 real pairs, 600x400), low light only:
  one `restore` per photo (pipeline.restore.restore_scene on that photo alone, which gives the
  photo restored in 2D), scored against high/;
- the 20 held-out SICE brackets (data.brackets.VALIDATION_BRACKETS) in both directions, with the
  pairing rule of data/brackets.py (target: the frame nearest a mean of 0.45; low light: the
  frames at most half as bright; over-exposure: those with at most half the headroom), every
  pair of each mode, each input restored as a one-photo `restore` like LOL (low-light model for
  dark inputs, over-exposure model for bright ones). Frames: the fixed validation crops of
  training (train/bracket_samples.py: the box of the head configs' network aspect, 4:3, at the
  position seeded by VALIDATION_SEED) but at the photos' resolution (512x384), not resized to the
  network's 224x168: a restore sees the photo at its own size.

Metrics per image: PSNR, SSIM, PSNR at the reference's mean grey (`psnr_gt_mean`) and sharpness
(eval.metrics, through pipeline.quality.QualityMeter as `eval` scores them); the brightness error
in stops (log2 of mean linear luminance, output over reference: negative is too dark) and the
mean CIE Lab chroma of the output and of the reference (eval.appearance_stats). Per source: the
mean over its images (chroma ratio: mean output chroma over mean reference chroma; |stops| the
mean absolute error). Mean over sources: each source's number weighs the same (low light: buu,
shrub, LOL, brackets; over-exposure: buu, shrub, brackets), LOM by its holdout protocol.

    .venv/bin/python benchmarks/appearance_dev.py            # full run, rewrites the model-card section
    .venv/bin/python benchmarks/appearance_dev.py --quick    # 3 LOL photos, 6 pairs a direction, holdout only
    .venv/bin/python benchmarks/appearance_dev.py --checkpoint-low-light runs/x/final.safetensors \
        --exposure-prior 0.5 --json out/x.json              # an experiment: table and JSON, no doc update

From Python (an experiment choosing a constant on the mean):

    from appearance_dev import RestoreOptions, run_dev_benchmark
    document = run_dev_benchmark(RestoreOptions(exposure_prior=0.5))
    document["mean"]["low-light"]["lumos3d"]["psnr"]
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import cv2
import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cli_runs import SHARED  # noqa: E402
from report import check_result_file, machine_description, markdown_table, table_section, write_section  # noqa: E402

from lumos3d_cli.data.augment import crop_box  # noqa: E402
from lumos3d_cli.data.brackets import BracketDataset, read_srgb  # noqa: E402
from lumos3d_cli.data.degradations import MODES  # noqa: E402
from lumos3d_cli.eval.appearance_stats import appearance_stats  # noqa: E402
from lumos3d_cli.eval.contact_sheet import contact_sheet  # noqa: E402
from lumos3d_cli.eval.metrics import auto_gamma  # noqa: E402
from lumos3d_cli.io.image_files import list_images  # noqa: E402
from lumos3d_cli.io.json_text import json_text  # noqa: E402
from lumos3d_cli.io.images import ImageBatch  # noqa: E402
from lumos3d_cli.model.bundled_models import resolve_checkpoint  # noqa: E402
from lumos3d_cli.model.lumos3d import Lumos3D  # noqa: E402
from lumos3d_cli.pipeline.evaluation import eval_contact_sheet, evaluate_lom  # noqa: E402
from lumos3d_cli.pipeline.lom_eval import PROTOCOLS  # noqa: E402
from lumos3d_cli.pipeline.model_loading import load_restoration_model  # noqa: E402
from lumos3d_cli.pipeline.choices import DEFAULT_RESTORE_PRESET, EXPOSURE_KEYS  # noqa: E402
from lumos3d_cli.pipeline.presets import RESTORE_PRESETS, RestorePreset, get_restore_preset  # noqa: E402
from lumos3d_cli.pipeline.quality import QualityMeter  # noqa: E402
from lumos3d_cli.pipeline.restore import restore_scene  # noqa: E402
from lumos3d_cli.train.bracket_samples import VALIDATION_SEED, validation_indices  # noqa: E402
from lumos3d_cli.train.config import load_config  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MODEL_CARD = REPO / "docs" / "model-card.md"
SECTION = "appearance-dev"
DEFAULT_JSON = REPO / "out" / "appearance_dev.json"

LOM_SCENES = ("buu", "shrub")
SOURCES = {"low-light": ("buu", "shrub", "lol", "brackets"), "over-exposure": ("buu", "shrub", "brackets")}
SOURCE_LABELS = {"buu": "LOM buu", "shrub": "LOM shrub", "lol": "LOL eval15", "brackets": "SICE held-out brackets"}
MEAN_PROTOCOL = "holdout"  # the LOM protocol the mean over sources uses (context when only it ran)
METRICS = ("psnr", "ssim", "psnr_gt_mean", "sharpness", "stops", "stops_abs", "chroma", "chroma_reference", "chroma_ratio")
METHODS = ("lumos3d", "gamma")

logger = logging.getLogger("appearance_dev")


@dataclass(frozen=True)
class RestoreOptions:
    """What is restored and how: the checkpoint of each mode (None: the bundled model), the preset
    and `restore`'s options over it (None: the preset's), the geometry source and the device."""

    checkpoint_low_light: str | None = None
    checkpoint_over_exposure: str | None = None
    preset: str = DEFAULT_RESTORE_PRESET
    refine_steps: int | None = None
    max_gaussians: int | None = None
    gaussian_grid: float | None = None
    exposure_prior: float | None = None
    fill_unobserved: bool | None = None
    geometry: str = "auto"
    device: str = "cpu"
    exposure_key: str | None = None

    def checkpoint(self, mode: str) -> str | None:
        return self.checkpoint_low_light if mode == "low-light" else self.checkpoint_over_exposure

    def settings(self) -> RestorePreset:
        return get_restore_preset(self.preset, self.refine_steps, self.max_gaussians, self.gaussian_grid,
                                  self.exposure_prior, self.fill_unobserved, exposure_key=self.exposure_key)

    @property
    def is_default(self) -> bool:
        return self == RestoreOptions()


@dataclass(frozen=True)
class Subset:
    """How much of each source: the modes, the sources, the LOM protocols, and at most this many
    LOL photos / bracket pairs per direction (None: all; a subset is spread evenly over them)."""

    modes: tuple[str, ...] = MODES
    sources: tuple[str, ...] = ("buu", "shrub", "lol", "brackets")
    protocols: tuple[str, ...] = PROTOCOLS
    lol_photos: int | None = None
    bracket_pairs: int | None = None

    @property
    def is_full(self) -> bool:
        return self == Subset()


QUICK = Subset(protocols=("holdout",), lol_photos=3, bracket_pairs=6)


# ---------------------------------------------------------------------------------------------
# per-image rows and their summaries


def _image_rows(quality: list[dict], images: Sequence[torch.Tensor], references: Sequence[torch.Tensor],
                names: Sequence[str]) -> list[dict]:
    """QualityMeter rows (psnr, psnr_gt_mean, ssim, sharpness) with the appearance statistics."""
    stats = appearance_stats(images, references)
    return [{"name": name, **{k: row[k] for k in ("psnr", "psnr_gt_mean", "ssim", "sharpness")}, **extra}
            for name, row, extra in zip(names, quality, stats)]


def summarise(rows: list[dict]) -> dict[str, float]:
    """The mean of each metric over `rows`; |stops| the mean absolute error; the chroma ratio is
    the mean output chroma over the mean reference chroma."""
    def mean(values):
        values = list(values)
        return sum(values) / len(values) if values else math.nan

    summary = {k: mean(r[k] for r in rows) for k in ("psnr", "ssim", "psnr_gt_mean", "sharpness", "stops", "chroma",
                                                      "chroma_reference")}
    summary["stops_abs"] = mean(abs(r["stops"]) for r in rows)
    summary["chroma_ratio"] = summary["chroma"] / summary["chroma_reference"] if summary["chroma_reference"] else math.nan
    summary["images"] = len(rows)
    return summary


SHEET_ROWS = 6  # one-photo sources: images in a contact sheet, spread evenly


def _write_sheet(path: Path, sheet: np.ndarray) -> None:
    """An RGB uint8 picture as PNG."""
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.ascontiguousarray(sheet[..., ::-1]))


def _entry(ours: list[dict], gamma: list[dict], seconds: float, **extra) -> dict:
    return {"lumos3d": summarise(ours), "gamma": summarise(gamma), "seconds": round(seconds, 1),
            "images": {"lumos3d": ours, "gamma": gamma}, **extra}


# ---------------------------------------------------------------------------------------------
# the sources


def lom_entries(options: RestoreOptions, mode: str, protocol: str, scenes: Sequence[str], meter: QualityMeter,
                shared: Path = SHARED, sheets: Path | None = None) -> dict[str, dict]:
    """`lumos3d eval` (evaluate_lom) on the LOM scenes under one protocol -> "<scene>/<protocol>" ->
    entry; with `sheets`, eval's contact sheet of each scene is written there."""
    started = time.perf_counter()
    report = evaluate_lom(shared / "lom", list(scenes), mode, protocol, options.checkpoint(mode), options.preset,
                          options.geometry, device=options.device, refine_steps=options.refine_steps,
                          max_gaussians=options.max_gaussians, gaussian_grid=options.gaussian_grid,
                          exposure_prior=options.exposure_prior, fill_unobserved=options.fill_unobserved,
                          exposure_key=options.exposure_key)
    entries = {}
    for result in report.scenes:
        references = list(result.references)
        ours = _image_rows(result.ours, result.renders, references, result.test_frames)
        gamma = _image_rows(result.baseline, list(result.baseline_images), references, result.test_frames)
        if sheets is not None:
            _write_sheet(sheets / f"{mode}-{result.scene}-{protocol}.png", eval_contact_sheet(result, mode, True))
        entries[f"{result.scene}/{protocol}"] = _entry(
            ours, gamma, result.seconds, views_used=result.views_used, geometry=result.geometry.get("source"),
            uncovered=result.uncovered, gaussians=result.gaussians,
        )
    logger.info("LOM %s %s: %s (%.0f s)", mode, protocol, ", ".join(scenes), time.perf_counter() - started)
    return entries


def restore_one_photo(model: Lumos3D, settings: RestorePreset, options: RestoreOptions, mode: str,
                      photo: torch.Tensor, path: Path) -> torch.Tensor:
    """One photo [3, H, W] through the restore job alone (what `lumos3d restore PHOTO` writes to
    restored/): [3, H, W] in [0, 1]."""
    height, width = photo.shape[-2:]
    batch = ImageBatch(photo[None].contiguous(), [path], [(int(width), int(height))], ["photo"])
    scene = restore_scene(batch, model, settings, options.geometry, None, None, mode)
    if scene.view_source != "photo restoration":
        logger.warning("%s: the restore rendered the scene (%s) instead of restoring the photo in 2D", path,
                       scene.view_source)
    return scene.restored[0].clamp(0, 1)


def _one_photo_entry(options: RestoreOptions, mode: str, pairs: Sequence[tuple[str, torch.Tensor, torch.Tensor, Path]],
                     meter: QualityMeter, sheet: Path | None = None) -> dict:
    """pairs (name, input [3, H, W], reference [3, H, W], input path) restored one photo at a time;
    with `sheet`, a contact sheet of SHEET_ROWS of them (input | ours | gamma | reference) is written there."""
    started = time.perf_counter()
    model = load_restoration_model(resolve_checkpoint(options.checkpoint(mode), mode), options.device)
    settings = options.settings()
    names, restored, gamma, references = [], [], [], []
    for name, photo, reference, path in pairs:
        restored.append(restore_one_photo(model, settings, options, mode, photo, path))
        gamma.append(auto_gamma(photo))
        references.append(reference)
        names.append(name)
    ours = _image_rows(meter.measure(restored, references), restored, references, names)
    base = _image_rows(meter.measure(gamma, references), gamma, references, names)
    if sheet is not None:
        rows = [[(pairs[i][1], f"{names[i]} input ({mode})"),
                 (restored[i], f"lumos3d  {ours[i]['psnr']:.2f} dB  {ours[i]['ssim']:.3f}  {ours[i]['stops']:+.2f} st"),
                 (gamma[i], f"gamma  {base[i]['psnr']:.2f} dB  {base[i]['ssim']:.3f}"), (references[i], "reference")]
                for i in validation_indices(len(names), SHEET_ROWS)]
        _write_sheet(sheet, contact_sheet(rows))
    return _entry(ours, base, time.perf_counter() - started)


def lol_pairs(count: int | None, shared: Path = SHARED) -> list[tuple[str, torch.Tensor, torch.Tensor, Path]]:
    """LOL eval15's (name, low, high, low path), all or `count` spread evenly (natural order)."""
    low = list_images(shared / "lol_eval15" / "low")
    chosen = [low[int(i)] for i in validation_indices(len(low), count)]
    return [(path.stem, read_srgb(path), read_srgb(shared / "lol_eval15" / "high" / path.name), path) for path in chosen]


def bracket_crop_pairs(mode: str, count: int | None, shared: Path = SHARED) -> list[tuple[str, torch.Tensor, torch.Tensor, Path]]:
    """The held-out pairs of `mode` (all, or `count` spread evenly over them as validation spreads
    a subset) on the fixed validation crops at the photos' resolution: (name, input, target, path)."""
    config = load_config(REPO / "configs" / f"operator-head-{mode}.yaml")
    network_size = (config.data.width, config.data.height)  # what training validation resizes the crops to
    root = shared / "brackets"
    at_network = BracketDataset(root, mode, "validation", network_size, (1.0, 1.0), flip=False, seed=VALIDATION_SEED)
    first = read_srgb(at_network.pairs[0].input_path)
    # The crop's own size: the box of the network's aspect at scale 1 (its size does not depend on
    # the draw); a dataset of that size draws the same boxes and resizes them by 1, i.e. not at all.
    _, _, crop_width, crop_height = crop_box(first.shape[-1], first.shape[-2], *network_size, 1.0, np.random.default_rng(0))
    at_photo = BracketDataset(root, mode, "validation", (crop_width, crop_height), (1.0, 1.0), flip=False,
                              seed=VALIDATION_SEED)
    pairs = []
    for index in validation_indices(len(at_photo), count):
        sample, check = at_photo[int(index)], at_network[int(index)]
        pair = at_photo.pairs[int(index)]
        resized = F.interpolate(sample["images"], size=network_size[::-1], mode="bilinear",
                                                  align_corners=False, antialias=True).clamp(0, 1)
        if (resized - check["images"]).abs().max() > 1e-4:
            raise RuntimeError(f"{pair.input_path}: the crop differs from training validation's")
        pairs.append((f"{pair.bracket}/{pair.input_path.name}", sample["images"][0], sample["targets"][0], pair.input_path))
    return pairs


# ---------------------------------------------------------------------------------------------
# the benchmark


def mean_over_sources(entries: dict[str, dict], mode: str, sources: Sequence[str]) -> dict:
    """The mean of each metric over the sources of `mode` that ran (LOM by MEAN_PROTOCOL, else
    context), each source weighing the same, for both methods."""
    chosen = []
    for source in SOURCES[mode]:
        if source not in sources:
            continue
        if source in LOM_SCENES:
            key = next((f"{source}/{p}" for p in (MEAN_PROTOCOL, "context") if f"{source}/{p}" in entries), None)
        else:
            key = source if source in entries else None
        if key is not None:
            chosen.append(key)
    mean = {"sources": chosen}
    for method in METHODS:
        mean[method] = {k: sum(entries[key][method][k] for key in chosen) / len(chosen) if chosen else math.nan
                        for k in METRICS}
    return mean


def run_dev_benchmark(options: RestoreOptions = RestoreOptions(), subset: Subset = Subset(), shared: Path = SHARED,
                      on_entry: Callable[[str, str, dict], None] | None = None, sheets: Path | None = None) -> dict:
    """The benchmark with `options` on `subset` -> the document (also what --json writes):
    {"options", "subset", "machine", "seconds", "sources": {mode: {entry: {"lumos3d": summary,
    "gamma": summary, "images": per-image rows, "seconds", ...}}}, "mean": {mode: {"sources",
    "lumos3d": summary, "gamma": summary}}}. Entries: "buu/holdout", "buu/context", "shrub/...",
    "lol", "brackets"; summaries hold METRICS. `on_entry(mode, entry, value)` after each; with
    `sheets`, a contact sheet per mode and entry is written into that folder."""
    started = time.perf_counter()
    meter = QualityMeter.create(None)
    document = {"options": asdict(options), "subset": asdict(subset), "machine": machine_description(),
                "sources": {}, "mean": {}}
    for mode in subset.modes:
        entries: dict[str, dict] = {}

        def add(name: str, entry: dict) -> None:
            entries[name] = entry
            if on_entry is not None:
                on_entry(mode, name, entry)

        scenes = [s for s in LOM_SCENES if s in subset.sources and s in SOURCES[mode]]
        for protocol in subset.protocols:
            if scenes:
                for name, entry in lom_entries(options, mode, protocol, scenes, meter, shared, sheets).items():
                    add(name, entry)
        if "lol" in subset.sources and "lol" in SOURCES[mode]:
            add("lol", _one_photo_entry(options, mode, lol_pairs(subset.lol_photos, shared), meter,
                                        None if sheets is None else sheets / f"{mode}-lol.png"))
        if "brackets" in subset.sources:
            add("brackets", _one_photo_entry(options, mode, bracket_crop_pairs(mode, subset.bracket_pairs, shared), meter,
                                             None if sheets is None else sheets / f"{mode}-brackets.png"))
        document["sources"][mode] = entries
        document["mean"][mode] = mean_over_sources(entries, mode, subset.sources)
    document["seconds"] = round(time.perf_counter() - started, 1)
    return document


# ---------------------------------------------------------------------------------------------
# the report


def _cells(summary: dict) -> list[str]:
    return [f"{summary['psnr']:.2f}", f"{summary['ssim']:.3f}", f"{summary['psnr_gt_mean']:.2f}",
            f"{summary['sharpness']:.2f}", f"{summary['stops']:+.2f} ({summary['stops_abs']:.2f})",
            f"{summary['chroma_ratio']:.2f} ({summary['chroma']:.1f} / {summary['chroma_reference']:.1f})"]


HEADER = ["mode, source", "method", "PSNR", "SSIM", "PSNR at GT mean", "sharpness", "brightness, stops (mean abs. error)",
          "chroma ratio (output / reference)"]


def _source_label(document: dict, mode: str, entry: str) -> str:
    value = document["sources"][mode][entry]
    count = value["lumos3d"]["images"]
    if "/" in entry:
        scene, protocol = entry.split("/")
        return f"{SOURCE_LABELS[scene]}, {protocol} ({count} test frames)"
    return f"{SOURCE_LABELS[entry]} ({count} {'photos' if entry == 'lol' else 'pairs'})"


def report_table(document: dict) -> str:
    """One markdown table: per mode, each source (ours under each protocol, holdout first; then the
    gamma curve once), then the mean over the sources for both."""
    rows = []
    for mode, entries in document["sources"].items():
        mean = document["mean"][mode]
        for source in SOURCES[mode]:
            names = [f"{source}/{p}" for p in (MEAN_PROTOCOL, "context") if f"{source}/{p}" in entries]
            names += [source] if source in entries else []
            for entry in names:
                rows.append([f"{mode}: {_source_label(document, mode, entry)}", "lumos3d", *_cells(entries[entry]["lumos3d"])])
            if names:  # the gamma curve scores the same frames under every protocol
                rows.append([f"{mode}: {SOURCE_LABELS[source]}", "gamma", *_cells(entries[names[0]]["gamma"])])
        count = len(mean["sources"])
        label = f"{mode}: mean of {count} source{'' if count == 1 else 's'}"
        rows.append([f"**{label}**", "**lumos3d**", *(f"**{c}**" for c in _cells(mean["lumos3d"]))])
        rows.append([label, "gamma", *_cells(mean["gamma"])])
    return markdown_table(HEADER, rows)


def _description(document: dict) -> str:
    options = document["options"]
    minutes = document["seconds"] / 60
    return (
        "Every real source the project may choose constants on, with the blind auto-gamma curve beside each. "
        "LOM buu and shrub: `lumos3d eval` (`pipeline.evaluation.evaluate_lom`), both protocols, registered "
        "cameras (`--geometry auto`). LOL eval15 (low light only) and the 20 held-out SICE brackets (every pair of "
        "each mode by data/brackets.py's rule; dark inputs through the low-light model, bright ones through the "
        "over-exposure model): one `restore` per photo (the photo restored in 2D), the brackets on training "
        "validation's fixed crops (the 4:3 box at `VALIDATION_SEED`'s position) at 512x384 instead of the network's "
        "224x168. Models: the bundled ones"
        + ("" if options["checkpoint_low_light"] is None and options["checkpoint_over_exposure"] is None
           else f" (low light: {options['checkpoint_low_light']}, over-exposure: {options['checkpoint_over_exposure']})")
        + f", preset `{options['preset']}` with its defaults. Brightness: log2 of the mean linear luminance, output "
        "over reference (negative: too dark), the mean over images and in brackets the mean absolute error. "
        "Chroma: mean CIE Lab a\\*b\\* radius (`eval/appearance_stats.py`), the ratio of the output's to the "
        "reference's (the mean rows: the mean of the sources' ratios). Sharpness: detail energy over the "
        "reference's (1 = as sharp). Means: each source weighs the same (low light 4 sources, over-exposure 3: LOL "
        "has no over-exposed photos), LOM by its holdout protocol. Written by `benchmarks/appearance_dev.py` "
        f"(full run: {minutes:.0f} min wall)."
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="3 LOL photos, 6 bracket pairs per direction, holdout only (no doc update)")
    parser.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    parser.add_argument("--sources", nargs="+", choices=("buu", "shrub", "lol", "brackets"),
                        default=["buu", "shrub", "lol", "brackets"])
    parser.add_argument("--checkpoint-low-light", default=None, help="checkpoint for low light (default: bundled)")
    parser.add_argument("--checkpoint-over-exposure", default=None, help="checkpoint for over-exposure (default: bundled)")
    parser.add_argument("--preset", choices=tuple(RESTORE_PRESETS), default=DEFAULT_RESTORE_PRESET)
    parser.add_argument("--refine-steps", type=int, default=None)
    parser.add_argument("--max-gaussians", type=int, default=None)
    parser.add_argument("--gaussian-grid", type=float, default=None)
    parser.add_argument("--exposure-prior", type=float, default=None)
    parser.add_argument("--exposure-key", choices=EXPOSURE_KEYS, default=None)
    parser.add_argument("--black-unobserved", action="store_true", help="leave uncovered pixels black (LOM renders)")
    parser.add_argument("--geometry", default="auto")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--json", type=Path, default=DEFAULT_JSON, help=f"where to write every number (default {DEFAULT_JSON})")
    parser.add_argument("--no-doc", action="store_true", help="do not rewrite the model-card section")
    parser.add_argument("--sheets", type=Path, default=None, help="write a contact sheet per mode and source into this folder")
    parser.add_argument("--verbose", action="store_true", help="the pipeline's progress messages too")
    parser.add_argument("--from-json", type=Path, default=None,
                        help="run nothing: print the table of an earlier run's JSON (and write the doc if it was a full default run)")
    args = parser.parse_args()
    if (refusal := check_result_file(args.json)) is not None:
        parser.error(f"--json {refusal}")
    if args.from_json is not None and not args.from_json.is_file():
        parser.error(f"--from-json {args.from_json}: no such file")
    if args.from_json is None and not any(source in SOURCES[mode] for mode in args.modes for source in args.sources):
        parser.error(f"--modes {' '.join(args.modes)} with --sources {' '.join(args.sources)} select nothing "
                     f"(over-exposure has no {SOURCE_LABELS['lol']} photos)")
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")
    logger.setLevel(logging.INFO)
    options = RestoreOptions(args.checkpoint_low_light, args.checkpoint_over_exposure, args.preset, args.refine_steps,
                             args.max_gaussians, args.gaussian_grid, args.exposure_prior,
                             False if args.black_unobserved else None, args.geometry, args.device, args.exposure_key)
    subset = replace(QUICK if args.quick else Subset(), modes=tuple(args.modes), sources=tuple(args.sources))

    def progress(mode: str, entry: str, value: dict) -> None:
        ours, gamma = value["lumos3d"], value["gamma"]
        logger.info("%s %s: %.2f dB / %.3f, %+.2f stops, chroma x%.2f (gamma %.2f / %.3f) in %.0f s", mode, entry,
                    ours["psnr"], ours["ssim"], ours["stops"], ours["chroma_ratio"], gamma["psnr"], gamma["ssim"],
                    value["seconds"])

    if args.from_json is not None:
        document = json.loads(args.from_json.read_text())
        options, subset = RestoreOptions(**document["options"]), Subset(**{k: tuple(v) if isinstance(v, list) else v
                                                                            for k, v in document["subset"].items()})
    else:
        document = run_dev_benchmark(options, subset, on_entry=progress, sheets=args.sheets)
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json_text(document, str(args.json)))
        print(f"wrote {args.json}")
    table = report_table(document)
    print(table)
    print(f"\n{document['seconds'] / 60:.1f} min on {document['machine']}")
    if args.no_doc or not subset.is_full or not options.is_default:
        print("model card not updated (only a full run of the bundled models with the default options writes it)")
        return
    write_section(SECTION, table_section("### Development benchmark (all real sources)", _description(document), table),
                  MODEL_CARD)
    print(f"wrote the {SECTION} section of {MODEL_CARD}")


if __name__ == "__main__":
    main()
