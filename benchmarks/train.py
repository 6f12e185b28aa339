"""Training speed: steps per second and peak memory of the tiny configuration (teacher and
student stage) on this machine's CPU, and on CUDA when available.

    .venv/bin/python benchmarks/train.py            # rewrites the "training" section of docs/performance.md
    .venv/bin/python benchmarks/train.py --quick    # fewer steps, no doc update
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import torch
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import SHARED_DATA, machine_description, markdown_table, peak_rss_mib, run_child, write_section  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SCENES = SHARED_DATA / "scenes"


def _config(folder: Path, stage: str, views: int, width: int, height: int, device: str, teacher: str | None) -> Path:
    values = {
        "stage": stage, "output": str(folder / stage), "model": teacher or "tiny", "teacher": teacher,
        "data": {"root": str(SCENES), "views": views, "width": width, "height": height},
        "optim": {"steps": 1000, "warmup_steps": 10}, "log_every": 1, "checkpoint_every": 0, "device": device,
    }
    path = folder / f"{stage}.yaml"
    path.write_text(yaml.safe_dump(values))
    return path


def measure(config: Path, steps: int) -> dict:
    """Seconds per step (median after two warm-up steps) and peak RSS of one training process."""
    from lumos3d_cli.train.config import load_config
    from lumos3d_cli.train.distributed import setup_distributed
    from lumos3d_cli.train.trainer import Trainer

    settings = load_config(config)
    trainer = Trainer(settings, setup_distributed(settings.device))
    trainer.nonfinite_in_a_row = trainer.nonfinite_total = 0
    times = []
    for step in range(steps + 2):
        start = time.perf_counter()
        trainer.step(step)
        if settings.device == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - start)
    steady = statistics.median(times[2:])
    gpu_peak = torch.cuda.max_memory_allocated() / 2**20 if settings.device == "cuda" else None
    return {"seconds_per_step": steady, "peak_rss_mib": peak_rss_mib(), "gpu_peak_mib": gpu_peak,
            "parameters": sum(p.numel() for p in trainer.model.parameters())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--measure", nargs=2, metavar=("CONFIG", "STEPS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        print(json.dumps(measure(Path(args.measure[0]), int(args.measure[1]))))
        return
    steps = 3 if args.quick else 8
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    shapes = [(2, 112, 84), (4, 224, 168)] if not args.quick else [(2, 112, 84)]
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        from lumos3d_cli.model.checkpoints import save_checkpoint
        from lumos3d_cli.model.lumos3d import build_model

        teacher = folder / "teacher.safetensors"
        save_checkpoint(build_model("tiny", seed=0), teacher)
        for device in devices:
            for views, width, height in shapes:
                for stage in ("teacher", "student"):
                    config = _config(folder, stage, views, width, height, device, str(teacher) if stage == "student" else None)
                    output = run_child([sys.executable, __file__, "--measure", str(config), str(steps)])
                    values = json.loads(output.strip().splitlines()[-1])
                    rows.append([device, stage, views, f"{width}×{height}", f"{values['seconds_per_step']:.2f}",
                                 f"{1 / values['seconds_per_step']:.2f}", f"{values['peak_rss_mib']:.0f}",
                                 "—" if values["gpu_peak_mib"] is None else f"{values['gpu_peak_mib']:.0f}"])
                    print(rows[-1], flush=True)
    text = "\n\n".join([
        "## Training (tiny architecture)",
        f"Machine: {machine_description()}. Script: `benchmarks/train.py`. One process, batch of one "
        "scene, fp32, the full objective of each stage (teacher: rendering + pose + sparse depth; "
        "student: reconstruction + distillation from a frozen teacher + Lumos loss without VGG "
        "weights, i.e. image L1 and voxel statistics on an RGB pyramid). Median of "
        f"{steps} steps after two warm-up steps, data loading included.",
        markdown_table(["device", "stage", "views", "size", "s / step", "steps / s", "peak RSS MiB", "GPU peak MiB"], rows),
    ])
    print(text)
    if not args.quick:
        write_section("training", text)


if __name__ == "__main__":
    main()
