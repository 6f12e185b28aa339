"""The paper's ablations at the tiny scale, on LOM buu: the Lumos loss built up term by term, the
teacher's input (normal-light vs degraded images), seed-to-seed spread of the full objective,
and one model for both modes vs two. Each variant is a student trained with
`lumos3d train CONFIG output=RUN OVERRIDES` and scored with `lumos3d eval` (balanced preset,
context and holdout protocols, camera AUC@30).

    .venv/bin/python benchmarks/ablations.py           # score the runs in runs/, rewrite the table
    .venv/bin/python benchmarks/ablations.py --train   # first train the variants whose run is missing

Training one variant takes 30-60 min on 2 CPU cores; the scoring alone about a minute per
variant and mode. The table is the "ablations" section of docs/model-card.md.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cli_runs import REPO, evaluate_buu, run_lumos3d  # noqa: E402
from report import machine_description, markdown_table, write_section  # noqa: E402

MODEL_CARD = REPO / "docs" / "model-card.md"


@dataclass(frozen=True)
class Variant:
    """One trained student: where its run lives and how it was made."""

    label: str
    run: str
    config: str
    overrides: tuple[str, ...] = ()
    modes: tuple[str, ...] = ("low-light",)


LOW_LIGHT = "configs/default-low-light.yaml"
VARIANTS = (
    Variant("full objective (shipped, seed 1)", "runs/default-low-light", LOW_LIGHT),
    Variant("full objective, seed 2", "runs/seed2-low-light", LOW_LIGHT, ("seed=2",)),
    Variant("reconstruction + distillation, no Lumos loss", "runs/ablation-no-lumos", LOW_LIGHT, ("loss.lumos=0",)),
    Variant("+ Lumos image term (no voxel term)", "runs/ablation-image-only", LOW_LIGHT, ("loss.voxel=0",)),
    Variant("teacher sees the degraded images", "runs/ablation-teacher-degraded", LOW_LIGHT,
            ("teacher_input=degraded",)),
    Variant("over-exposure model (shipped, seed 2)", "runs/default-over-exposure", "configs/default-over-exposure.yaml",
            modes=("over-exposure",)),
    Variant("one model for both modes, 1,000 steps", "runs/ablation-mixed", "configs/ablation-mixed.yaml",
            ("optim.steps=1000",), ("low-light", "over-exposure")),
)


def _train(variant: Variant) -> None:
    print(f"training {variant.run} ({variant.label})", flush=True)
    run_lumos3d(["train", variant.config, f"output={variant.run}", *variant.overrides])


def _training_minutes(run: Path) -> float:
    """Steps times the median logged step time (the runs log every 10 steps)."""
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if line.strip()]
    return (rows[-1]["step"] + 1) * statistics.median(r["seconds"] for r in rows) / 60


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", action="store_true", help="train the variants whose run folder has no final weights")
    parser.add_argument("--no-doc", action="store_true", help="print only")
    args = parser.parse_args()
    missing = [v for v in VARIANTS if not (REPO / v.run / "final.safetensors").is_file()]
    if missing and not args.train:
        commands = "\n".join(f"  lumos3d train {v.config} output={v.run} {' '.join(v.overrides)}" for v in missing)
        sys.exit(f"no trained weights for {len(missing)} variant(s); train them (or pass --train):\n{commands}")
    for variant in missing:
        _train(variant)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for variant in VARIANTS:
            run = REPO / variant.run
            for mode in variant.modes:
                scores = evaluate_buu(mode, ["--checkpoint", str(run / "final.safetensors")], f"{folder}/{run.name}-{mode}")
                (context, _, cameras), (holdout, _, _) = scores["context"], scores["holdout"]
                rows.append([
                    variant.label, mode, f"`{' '.join(variant.overrides)}`" if variant.overrides else "",
                    f"{context['psnr']:.2f} / {context['ssim']:.3f}", f"{holdout['psnr']:.2f} / {holdout['ssim']:.3f}",
                    f"{cameras['auc_30']:.3f}", f"{_training_minutes(run):.0f}",
                ])
                print(rows[-1], flush=True)
    text = "\n\n".join([
        "### Ablations (tiny scale, shipped teacher)",
        f"Script: `benchmarks/ablations.py` (scoring machine: {machine_description()}). Students trained with "
        "the config of their row (`lumos3d train CONFIG output=RUN OVERRIDES`), everything else equal: "
        "same teacher, 1,000 steps, seed 1 unless stated; scored with `lumos3d eval` on buu (balanced "
        "preset). Training minutes are steps × median step time; most runs shared the 2 cores with one "
        "other run (1 thread each). The Lumos content term is off in every row (no VGG-19 weights on this "
        "machine), so the Lumos loss here is the image L1 term plus the voxel statistics term.",
        markdown_table(["student", "mode", "overrides", "context PSNR / SSIM", "holdout PSNR / SSIM",
                        "cameras AUC@30", "train min"], rows),
    ])
    print(text)
    if not args.no_doc:
        write_section("ablations", text, MODEL_CARD)


if __name__ == "__main__":
    main()
