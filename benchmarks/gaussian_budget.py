"""Gaussian budget: how many Gaussians a restored scene keeps, its .ply size and the render PSNR
at its views, for the fusion's voxel size (one global size, or a multiple of each point's pixel
footprint) and the contribution pruning's threshold (rendered weight in pixels, over all views).

    .venv/bin/python benchmarks/gaussian_budget.py                    # tuning scenes, normal light
    .venv/bin/python benchmarks/gaussian_budget.py --lom buu          # report on LOM buu

Tuning scenes (`--scenes`, normal-light photos in ../shared/data/scenes) go through the bundled
low-light model with the default preset (cameras from structure-from-motion where it registers,
the network's depth), but the pixel Gaussians take the photos' colours averaged over each network
pixel, as an operator model colours them from its restored photos: the renders at every view
should then reproduce the photos, and the PSNR against them measures geometry, fusion and
pruning rather than colour restoration. LOM scenes restore low/ with the model's own colours and
score every frame against high/ (the context protocol of `lumos3d eval`, over all frames rather
than the test frames). "fidelity" is the PSNR of each pruned render against the unpruned render
of the same fusion: what pruning alone changed. "seconds": the fusion (unpruned rows) or the
weights (pruned rows). SfM and the network run once per scene; every fusion re-assembles the
same prediction as `pipeline.scene_stages.build_scene` does, and applies its sampling filter.
Prints markdown tables.
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import SHARED_DATA, machine_description, markdown_table, write_section  # noqa: E402

from lumos3d_cli.data.lom import read_lom_scene  # noqa: E402
from lumos3d_cli.eval.metrics import psnr  # noqa: E402
from lumos3d_cli.io.cameras import Cameras  # noqa: E402
from lumos3d_cli.io.gaussians import Gaussians  # noqa: E402
from lumos3d_cli.io.images import load_images  # noqa: E402
from lumos3d_cli.io.ply import write_ply  # noqa: E402
from lumos3d_cli.model.appearance.footprint import footprint_colours  # noqa: E402
from lumos3d_cli.model.appearance.gaussian_colours import with_operator_colours  # noqa: E402
from lumos3d_cli.model.bundled_models import resolve_checkpoint  # noqa: E402
from lumos3d_cli.model.lumos3d import Lumos3D  # noqa: E402
from lumos3d_cli.model.pixel_footprint import DEFAULT_FOOTPRINT_SCALE  # noqa: E402
from lumos3d_cli.pipeline.model_loading import load_restoration_model  # noqa: E402
from lumos3d_cli.pipeline.presets import RESTORE_PRESETS, get_restore_preset  # noqa: E402
from lumos3d_cli.pipeline.restore import render_views  # noqa: E402
from lumos3d_cli.pipeline.scene_job import SceneJob  # noqa: E402
from lumos3d_cli.pipeline.scene_stages import build_scene  # noqa: E402
from lumos3d_cli.pipeline.sampling_filter import apply_sampling_filter  # noqa: E402
from lumos3d_cli.render.contribution import rendered_weights  # noqa: E402
from lumos3d_cli.render.gaussian_budget import DEFAULT_MIN_WEIGHT, select_budget  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENES = SHARED_DATA / "scenes"
LOM = SHARED_DATA / "lom"
# Every normal-light scene whose photos share one size (british_museum's do not).
TUNING_SCENES = ("riverview", "llff_fern", "tnt_garden", "kitchen", "statue", "video_llff_horns", "room",
                 "video_dtu_scan_106", "video_fox", "video_fillerbuster_ramen", "video_vrnerf_kitchen")


@dataclass
class Case:
    """One scene to restore: photos [V, 3, H, W] the network sees, their names, the references
    [V, 3, H, W] the renders are scored against, and whether the Gaussians take their colours
    from the photos (tuning scenes) or from the model (LOM)."""

    name: str
    photos: torch.Tensor
    names: list[str]
    references: torch.Tensor
    photo_colours: bool


def photo_case(folder: Path) -> Case:
    batch = load_images(folder / "images")
    return Case(folder.name, batch.images, [path.name for path in batch.paths], batch.images, True)


def lom_case(name: str) -> Case:
    scene = read_lom_scene(LOM / name, "low-light")
    low = load_images([scene.degraded[f] for f in scene.frames])
    high = load_images([scene.reference[f] for f in scene.frames])
    return Case(f"LOM {name}", low.images, list(scene.frames), high.images, False)


class AssembleRecorder:
    """Stands in for `model.assemble` during one `build_scene` and keeps its arguments, so the
    same prediction and geometry can be fused again with other voxel sizes."""

    def __init__(self, model: Lumos3D):
        self.model, self.args, self.kwargs = model, (), {}

    def __call__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs
        return Lumos3D.assemble(self.model, *args, **kwargs)

    def recolour(self, photos: torch.Tensor) -> None:
        """Give the pixel Gaussians the colours of photos [V, 3, H, W] (the views the network saw)
        averaged over each network pixel, as an operator model colours them from restored photos."""
        prediction = self.args[0]
        height, width = prediction.depth.shape[-2:]
        colours = footprint_colours(photos, height, width)[None]
        params = with_operator_colours(prediction.params, colours, self.model.architecture.sh_degree)
        self.args = (replace(prediction, params=params), *self.args[1:])

    def fuse(self, footprint_scale: float | None, network_size: tuple[int, int]) -> Gaussians:
        """The scene fused again: with the architecture's one global voxel size (None) or voxels
        of `footprint_scale` pixel footprints, then the sampling filter of build_scene."""
        # build_scene fuses by footprint, so the recorded call carries a footprint_scale: the
        # fixed fusion must drop it, or it repeats the footprint fusion.
        kwargs = dict(self.kwargs) | {"voxel_size": None, "footprint_scale": footprint_scale}
        with torch.no_grad():
            output = Lumos3D.assemble(self.model, *self.args, **kwargs)
        extrinsics, intrinsics = self.args[1][0], self.args[2][0]
        cameras = Cameras(extrinsics.float(), intrinsics.float(), [network_size] * extrinsics.shape[0])
        return apply_sampling_filter(output.gaussians[0].detach().to(device="cpu"), cameras)


def build(case: Case, model: Lumos3D) -> tuple[SceneJob, AssembleRecorder]:
    """`build_scene` with the default preset (unrefined), recording its fusion's arguments."""
    recorder = AssembleRecorder(model)
    model.assemble = recorder
    try:
        # The forward pass only: refinement would change the Gaussians that the fusions re-assemble.
        built = build_scene(case.photos, case.names, model, get_restore_preset("balanced", refine_steps=0))
    finally:
        del model.assemble
    if case.photo_colours:
        recorder.recolour(case.photos[built.selected])
    return built, recorder


def mean_psnr(renders: list[torch.Tensor], references: list[torch.Tensor] | torch.Tensor) -> float:
    """Mean over views of the PSNR of renders [3, H, W] against references."""
    return sum(float(psnr(a, b)) for a, b in zip(renders, references)) / len(renders)


def ply_mib(gaussians: Gaussians) -> float:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "scene.ply"
        write_ply(path, gaussians)
        return path.stat().st_size / 2**20


def measure_case(case: Case, built: SceneJob, recorder: AssembleRecorder, footprints: list[float],
                 min_weights: list[float], resolutions: list[float]) -> list[list[object]]:
    """Rows of the table: each fusion unpruned, then pruned at each threshold and weight resolution."""
    sh_degree = get_restore_preset("balanced").sh_degree
    cameras = built.geometry.cameras
    references = case.references[[case.names.index(name) for name in cameras.names]]
    rows, baseline = [], None
    for footprint in [None, *footprints]:
        fusion = "fixed" if footprint is None else f"footprint x{footprint:g}"
        started = time.perf_counter()
        gaussians = recorder.fuse(footprint, built.network_size)
        fuse_seconds = time.perf_counter() - started
        full = render_views(gaussians, cameras, sh_degree).images
        score = mean_psnr(full, references)
        baseline = score if baseline is None else baseline
        rows.append([case.name, fusion, "-", "-", f"{len(gaussians):,}", f"{ply_mib(gaussians):.1f}", f"{score:.2f}",
                     f"{score - baseline:+.2f}", "-", f"{fuse_seconds:.1f}"])
        logging.info("%s", rows[-1])
        for resolution in resolutions:
            started = time.perf_counter()
            weights = rendered_weights(gaussians, cameras, resolution)
            seconds = time.perf_counter() - started
            for min_weight in min_weights:
                keep, report = select_budget(weights, min_weight)
                kept = gaussians.select(keep)
                renders = render_views(kept, cameras, sh_degree).images
                score = mean_psnr(renders, references)
                rows.append([
                    case.name, fusion, f"{resolution:g}", f"{min_weight:g}", f"{report.kept:,}", f"{ply_mib(kept):.1f}",
                    f"{score:.2f}", f"{score - baseline:+.2f}", f"{mean_psnr(renders, full):.1f}", f"{seconds:.1f}",
                ])
                logging.info("%s", rows[-1])
    return rows


HEADER = ["scene", "fusion", "weights at", "min weight px", "Gaussians", ".ply MiB", "PSNR dB", "Δ vs fixed",
          "fidelity dB", "seconds"]


SUMMARY_HEADER = ["fusion", "weights at", "min weight px", "Gaussians (all scenes)", "of the fusion's", ".ply MiB (all)",
                  "mean Δ PSNR vs fixed dB", "mean fidelity dB", "weights s (all)"]


def summary_rows(rows: list[list[object]]) -> list[list[object]]:
    """One row per (fusion, weights resolution, threshold) of `measure_case`'s rows: totals and
    means over the scenes; "of the fusion's": kept over the unpruned fusion's count."""
    def number(text: str) -> float:
        return float(str(text).replace(",", ""))

    unpruned = {(r[0], r[1]): number(r[4]) for r in rows if r[2] == "-"}
    groups: dict[tuple, list[list[object]]] = {}
    for row in rows:
        groups.setdefault((row[1], row[2], row[3]), []).append(row)
    summary = []
    for (fusion, resolution, min_weight), group in groups.items():
        kept = sum(number(r[4]) for r in group)
        share = kept / sum(unpruned[(r[0], fusion)] for r in group)
        fidelity = "-" if resolution == "-" else f"{sum(number(r[8]) for r in group) / len(group):.1f}"
        summary.append([fusion, resolution, min_weight, f"{kept:,.0f}", f"{share:.0%}", f"{sum(number(r[5]) for r in group):.1f}",
                        f"{sum(number(r[7]) for r in group) / len(group):+.2f}", fidelity,
                        f"{sum(number(r[9]) for r in group):.1f}"])
    return summary


def preset_budgets() -> str:
    """What each restore preset uses, read from the presets themselves: '`fast`: voxels of x1
    footprints, weights at 0.5, ...'."""
    return "; ".join(
        f"`{name}`: voxels of x{preset.voxel_scale:g} footprints, weights at {preset.budget_resolution:g}"
        for name, preset in RESTORE_PRESETS.items()
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="*", default=list(TUNING_SCENES), help="folders in ../shared/data/scenes")
    parser.add_argument("--lom", nargs="*", default=[], help="LOM scenes to report on (then no tuning scenes)")
    parser.add_argument("--footprints", nargs="*", type=float, default=[DEFAULT_FOOTPRINT_SCALE, 2 * DEFAULT_FOOTPRINT_SCALE],
                        help="voxel size as multiples of the pixel footprint (besides the fixed size)")
    parser.add_argument("--min-weights", nargs="*", type=float, default=[DEFAULT_MIN_WEIGHT, 1.0, 2.0])
    parser.add_argument("--resolutions", nargs="*", type=float, default=[1.0, 0.5], help="render scale of the weights")
    parser.add_argument("--no-doc", action="store_true", help="print the tables without editing docs/performance.md")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
    model = load_restoration_model(resolve_checkpoint(None, "low-light"), "cpu")
    cases = [lom_case(name) for name in args.lom] if args.lom else [photo_case(SCENES / name) for name in args.scenes]
    rows = []
    for case in cases:
        rows += measure_case(case, *build(case, model), args.footprints, args.min_weights, args.resolutions)
    text = "\n\n".join([
        "## Gaussian budget (fusion and contribution pruning)",
        f"Machine: {machine_description()}. Script: `benchmarks/gaussian_budget.py` "
        f"({'LOM ' + ', '.join(args.lom) if args.lom else f'{len(cases)} normal-light scenes of ../shared/data/scenes'}); "
        "preset `balanced` without refinement, bundled low-light model. " + __doc__.split("\n\n")[2].replace("\n", " "),
        "### Mean over the scenes",
        markdown_table(SUMMARY_HEADER, summary_rows(rows)),
        "The fixed voxel size is the model's one global size; the footprint fusions size each voxel by the "
        f"point's pixel footprint. `restore` prunes at {DEFAULT_MIN_WEIGHT:g} px; {preset_budgets()}.",
        "### Every scene",
        markdown_table(HEADER, rows),
    ])
    print(text)
    if not args.no_doc:
        write_section("gaussian-budget", text)


if __name__ == "__main__":
    main()
