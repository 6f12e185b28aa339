"""The `eval` job: the LOM protocol over several scenes, the report (a row per scene and method,
plus the mean), and writing it (metrics.json, metrics.csv, one contact sheet per scene)."""

from __future__ import annotations

import csv
import io
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lumos3d_cli.data.degradations import MODES
from lumos3d_cli.data.lom import LomScene, find_lom_scenes
from lumos3d_cli.errors import InputError
from lumos3d_cli.eval.contact_sheet import contact_sheet
from lumos3d_cli.io.file_digest import file_sha256
from lumos3d_cli.io.image_write import write_image
from lumos3d_cli.io.json_text import finite_document, json_text
from lumos3d_cli.model.appearance.exposure_prior import prior_strength
from lumos3d_cli.model.bundled_models import resolve_checkpoint
from lumos3d_cli.pipeline.choices import DEFAULT_RESTORE_PRESET
from lumos3d_cli.pipeline.eval_outputs import eval_outputs
from lumos3d_cli.pipeline.lom_eval import PROTOCOLS, SceneEvaluation, evaluate_lom_scene, read_lom_photos
from lumos3d_cli.pipeline.model_loading import load_restoration_model
from lumos3d_cli.pipeline.presets import check_max_views, get_restore_preset
from lumos3d_cli.pipeline.quality import QualityMeter, mean_metrics
from lumos3d_cli.pipeline.scene_geometry import check_geometry_source

BASELINES = ("gamma", "none")
METRIC_KEYS = ("psnr", "psnr_gt_mean", "ssim", "sharpness", "lpips", "seconds")
MEAN_ROW = "mean"  # the scene column of the rows that average the scenes


@dataclass
class EvalReport:
    """`document` is metrics.json; `rows` (also in it) one per scene and method plus a "mean" row
    per method; `scenes` the per-scene evaluations (images for the contact sheets)."""

    document: dict
    rows: list[dict]
    scenes: list[SceneEvaluation]
    methods: list[str]

    @property
    def mode(self) -> str:
        return self.document["mode"]


def _rows(results: list[SceneEvaluation], methods: list[str]) -> list[dict]:
    rows = []
    for result in results:
        rows.append({"scene": result.scene, "method": "lumos3d", **mean_metrics(result.ours), "seconds": result.seconds})
        if "gamma" in methods:
            rows.append({"scene": result.scene, "method": "gamma", **mean_metrics(result.baseline), "seconds": None})
    for method in methods:
        per_scene = [row for row in rows if row["method"] == method]
        rows.append({"scene": MEAN_ROW, "method": method, **mean_metrics(per_scene, METRIC_KEYS)})
    return rows


def evaluate_lom(
    root: Path | str, scenes: str | Sequence[str] | None = None, mode: str = "low-light", protocol: str = "context",
    checkpoint: Path | str | None = None, preset: str = DEFAULT_RESTORE_PRESET, geometry: str = "auto",
    max_views: int | None = None, device: str = "cpu", baseline: str = "gamma", lpips_weights: Path | str | None = None,
    on_scene: Callable[[str], None] | None = None, refine_steps: int | None = None, max_gaussians: int | None = None,
    gaussian_grid: float | None = None, exposure_prior: float | None = None, fill_unobserved: bool | None = None,
    densify: bool | None = None, exposure_key: str | None = None, depth_sweep: bool | None = None,
    on_start: Callable[[int], None] | None = None,
) -> EvalReport:
    """Evaluate restoration on the LOM-layout scenes under `root` (all, or those named) with the
    paper's protocol; `on_start(count)` is called once the scenes are found and the model is
    loaded (every setting checked), `on_scene(name)` after each scene. `refine_steps` overrides the
    preset's test-time refinement (fitted to the views in the scene, never to held-out ones),
    `max_gaussians` its Gaussian cap, `gaussian_grid` its grid of pixel Gaussians,
    `exposure_prior` its exposure prior's strength, `fill_unobserved` whether the renders' uncovered
    pixels are filled, `densify` whether refinement densifies, `exposure_key` the key the exposure
    prior pulls towards ("content" or "fixed"), `depth_sweep` whether the registered depth is
    refined by the neighbouring photos."""
    if mode not in MODES:
        raise InputError(f"{mode!r}: use one of {', '.join(MODES)}", parameter="mode")
    if protocol not in PROTOCOLS:
        raise InputError(f"{protocol!r}: use one of {', '.join(PROTOCOLS)}", parameter="protocol")
    if baseline not in BASELINES:
        raise InputError(f"{baseline!r}: use one of {', '.join(BASELINES)}", parameter="baseline")
    check_geometry_source(geometry)
    settings = get_restore_preset(preset, refine_steps, max_gaussians, gaussian_grid, exposure_prior, fill_unobserved,
                                  densify=densify, exposure_key=exposure_key, depth_sweep=depth_sweep)
    check_max_views(max_views)
    limit = settings.max_views if max_views is None else max_views
    found = find_lom_scenes(root, mode, scenes)
    for scene in found:
        _check_scene_fits_the_report(scene, protocol, limit)
    weights = resolve_checkpoint(checkpoint, mode)
    meter = QualityMeter.create(lpips_weights)
    photos = [read_lom_photos(scene) for scene in found]  # a bad photo in the last scene is refused before the first's work
    model = load_restoration_model(weights, device, mode)
    if on_start is not None:
        on_start(len(found))
    results = []
    for scene, scene_photos in zip(found, photos):
        results.append(evaluate_lom_scene(scene, model, settings, protocol, limit, meter, geometry, scene_photos,
                                          with_baseline=baseline == "gamma"))
        if on_scene is not None:
            on_scene(scene.name)
    methods = ["lumos3d"] + (["gamma"] if baseline == "gamma" else [])
    rows = _rows(results, methods)
    document = {
        "root": str(root), "mode": mode, "protocol": protocol, "preset": settings.name, "geometry": geometry,
        "refine_steps": settings.refine_steps, "refine_each_view": settings.refine_each_view,
        "max_gaussians": settings.max_gaussians,
        "gaussian_grid": settings.gaussian_grid, "exposure_prior": prior_strength(mode, settings.exposure_prior),
        "exposure_key": settings.exposure_key,
        "fill_unobserved": settings.fill_unobserved, "densify": settings.densify is not None,
        "depth_sweep": settings.depth_sweep is not None,
        "max_views": limit, "checkpoint": {"name": weights.name, "sha256": file_sha256(weights)},
        "lpips": meter.lpips_note, "rows": rows,
        "frames": {r.scene: {"test": r.test_frames, "views_used": r.views_used, "lumos3d": r.ours,
                             **({"gamma": r.baseline} if "gamma" in methods else {})} for r in results},
        "cameras": {r.scene: r.pose.as_dict() for r in results if r.pose is not None},
        "geometry_sources": {r.scene: r.geometry for r in results},
        "gaussians": {r.scene: r.gaussians for r in results},
        "uncovered": {r.scene: r.uncovered for r in results},
    }
    return EvalReport(document, rows, results, methods)


def _check_scene_fits_the_report(scene: LomScene, protocol: str, max_views: int) -> None:
    """InputError before any work for a scene the report cannot hold: one named like the mean
    rows, one with more test frames than `max_views` (every test frame goes through the network),
    or one whose test frames alone fill `max_views` under the holdout protocol (they go through the
    network but are left out of the scene, which then has no view to be built from)."""
    if scene.name == MEAN_ROW:
        raise InputError(f"{scene.root}: a scene named {MEAN_ROW!r} cannot be told from the report's mean rows; "
                         "rename its folder")
    if protocol == "holdout" and len(scene.test) >= len(scene.frames):
        raise InputError(f"{scene.root}: the holdout protocol needs views besides the test frames")
    if len(scene.frames) > max_views and len(scene.test) > max_views:
        raise InputError(f"{max_views}: {scene.name}'s {len(scene.test)} test frames must all go through the network; "
                         f"raise it to at least {len(scene.test)}", parameter="max_views")
    if protocol == "holdout" and len(scene.frames) > max_views and len(scene.test) >= max_views:
        raise InputError(f"{max_views}: under the holdout protocol {scene.name}'s {len(scene.test)} test frame(s) go "
                         "through the network but are left out of the scene, leaving no view to build it from; raise it "
                         f"above {len(scene.test)}", parameter="max_views")


def eval_contact_sheet(result: SceneEvaluation, mode: str, with_baseline: bool) -> np.ndarray:
    """One row per test frame: input | ours | baseline | ground truth, RGB uint8."""
    rows = []
    for index, frame in enumerate(result.test_frames):
        ours = result.ours[index]
        row = [(result.inputs[index], f"{result.scene} {frame} input ({mode})"),
               (result.renders[index], f"lumos3d  {ours['psnr']:.2f} dB  {ours['ssim']:.3f}")]
        if with_baseline:
            base = result.baseline[index]
            row.append((result.baseline_images[index], f"gamma  {base['psnr']:.2f} dB  {base['ssim']:.3f}"))
        row.append((result.references[index], "ground truth (high)"))
        rows.append(row)
    return contact_sheet(rows)


def write_eval_report(report: EvalReport, out: Path | str, inputs: Sequence[Path | str | None] = ()) -> None:
    """metrics.json, metrics.csv and contact_sheet_<scene>.png into `out`, all or nothing, never
    over a file lumos3d did not write nor over or into `inputs` or the LOM root the report read
    (io/output_set.py)."""
    inputs = [*inputs, report.document.get("root")]
    with eval_outputs(out, [result.scene for result in report.scenes], inputs).staged() as staging:
        (staging.root / "metrics.json").write_text(json_text(report.document, "metrics.json"))
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=["scene", "method", *METRIC_KEYS])
        writer.writeheader()
        writer.writerows(finite_document(report.rows, "metrics.csv", written_as="empty cells"))
        (staging.root / "metrics.csv").write_text(buffer.getvalue())
        for result in report.scenes:
            sheet = eval_contact_sheet(result, report.mode, "gamma" in report.methods)
            write_image(staging.root / f"contact_sheet_{result.scene}.png", sheet.astype(np.float32) / 255)
