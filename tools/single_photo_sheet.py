"""Restore single photos (each its own one-view scene) and put them on one contact sheet, with
the blind auto-gamma baseline beside them: for looking at a model's colour on real photos
without ground truth, e.g. ../shared/data/lowlight_single.

    .venv/bin/python tools/single_photo_sheet.py ../shared/data/lowlight_single -o sheet.png --count 6
    .venv/bin/python tools/single_photo_sheet.py photos/ -o sheet.png --mode over-exposure --checkpoint run/final.safetensors
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from lumos3d_cli.eval.contact_sheet import contact_sheet
from lumos3d_cli.eval.metrics import auto_gamma
from lumos3d_cli.io.image_files import list_images
from lumos3d_cli.io.image_write import write_image
from lumos3d_cli.io.images import load_images
from lumos3d_cli.model.bundled_models import resolve_checkpoint
from lumos3d_cli.pipeline.model_loading import load_restoration_model
from lumos3d_cli.pipeline.network_pass import even_subset
from lumos3d_cli.pipeline.choices import DEFAULT_RESTORE_PRESET
from lumos3d_cli.pipeline.presets import get_restore_preset
from lumos3d_cli.pipeline.restore import restore_scene


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("photos", type=Path)
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--count", type=int, default=6, help="photos, chosen evenly")
    parser.add_argument("--mode", default="low-light")
    parser.add_argument("--checkpoint", type=Path)
    parser.add_argument("--preset", default=DEFAULT_RESTORE_PRESET)
    args = parser.parse_args()
    paths = list_images(args.photos)
    paths = [paths[i] for i in even_subset(len(paths), args.count)]
    model = load_restoration_model(resolve_checkpoint(args.checkpoint, args.mode), "cpu")
    preset = get_restore_preset(args.preset)
    rows = []
    for path in paths:
        scene = restore_scene(load_images([path]), model, preset)
        rows.append([(scene.inputs[0], f"input {path.name}"), (scene.restored[0], "lumos3d"),
                     (auto_gamma(scene.inputs[0][None])[0], "auto-gamma")])
    write_image(args.output, contact_sheet(rows).astype(np.float32) / 255)
    print(f"wrote {args.output} ({len(rows)} photos)")


if __name__ == "__main__":
    main()
