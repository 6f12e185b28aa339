"""Write a restored scene to disk: the `.ply`, the cameras (transforms.json and a COLMAP model),
the restored views (each at its photo's own size), a contact sheet, a point preview,
summary.json and optionally an orbit video — all or nothing, and only over lumos3d's own
earlier outputs (io/output_set.py)."""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.eval.contact_sheet import contact_sheet
from lumos3d_cli.io.colmap import write_colmap_model
from lumos3d_cli.io.colour import srgb_to_linear
from lumos3d_cli.io.image_write import write_exr, write_image
from lumos3d_cli.io.json_text import finite_document, json_text
from lumos3d_cli.io.ply import write_ply
from lumos3d_cli.io.preview_glb import write_preview_glb
from lumos3d_cli.io.transforms_json import write_transforms_json
from lumos3d_cli.io.video import probe_video, video_kind
from lumos3d_cli.pipeline.restore import RestoredScene
from lumos3d_cli.pipeline.restore_paths import VIEW_FORMATS, check_view_format, restore_outputs
from lumos3d_cli.pipeline.orbit_video import write_orbit_video

logger = logging.getLogger(__name__)

def write_view(path: Path, image: torch.Tensor, output_format: str) -> None:
    """image [3, H, W] sRGB (any float dtype, any device) -> an 8/16-bit PNG, or a linear half-float EXR."""
    pixels = image.detach().float().permute(1, 2, 0).cpu().numpy()
    if output_format == "exr":
        write_exr(path, srgb_to_linear(np.clip(pixels, 0, 1)))
    else:
        write_image(path, pixels, bit_depth=VIEW_FORMATS[output_format][1])


def scene_contact_sheet(scene: RestoredScene) -> np.ndarray:
    """One row per input view: input | restored (with PSNR/SSIM when references were given) |
    reference. RGB uint8."""
    rows = []
    per_view = scene.metrics["views"] if scene.metrics is not None else None
    for index, name in enumerate(scene.names):
        label = "restored"
        if per_view is not None:
            label = f"restored  PSNR {per_view[name]['psnr']:.2f}  SSIM {per_view[name]['ssim']:.3f}"
        row = [(scene.inputs[index], f"input {name}"), (scene.restored[index], label)]
        if scene.references is not None:
            row.append((scene.references[index], "reference"))
        rows.append(row)
    return contact_sheet(rows)


def write_restored_scene(scene: RestoredScene, scene_path: Path | str, output_format: str = "png",
                         video: Path | str | None = None, inputs: Sequence[Path | str | None] = (),
                         on_video_frame: Callable[[], None] | None = None) -> dict:
    """Write every output of `scene` beside `scene_path` (a `.ply`), and an orbit `video` (.mp4 or
    .gif) when asked, and return the summary written to summary.json. The files appear together
    when all are written; a file in the way that lumos3d did not write, or an output that would
    touch an input (the scene's photos, what `restore` read them from: their folder, the poses,
    the references, the checkpoint; and `inputs`), refuses the write (io/output_set.py)."""
    scene_path = Path(scene_path)
    check_view_format(output_format)
    if video is not None:
        video_kind(video)
    suffix = VIEW_FORMATS[output_format][0]
    for name, image in zip(scene.names, scene.restored):  # a scene edited in Python: named here, not by a temporary file
        require_finite(f"restored view {name}", image)
    started = time.perf_counter()
    outputs = restore_outputs(scene_path, [*scene.input_paths, *scene.read_from, *inputs], video)
    with outputs.staged() as staging, ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        root = staging.root
        (root / "restored").mkdir()
        # The images are encoded on every core (OpenCV and OpenImageIO release the GIL) while this
        # thread writes the scene, its cameras and the preview: 25 views of 500x375 and the contact
        # sheet took 0.6 s on one core. The contact sheet goes first: the longest to encode.
        images = [pool.submit(lambda: write_image(root / "contact_sheet.png",
                                                  scene_contact_sheet(scene).astype(np.float32) / 255))]
        images += [pool.submit(write_view, root / "restored" / f"{Path(name).stem}{suffix}", image, output_format)
                   for name, image in zip(scene.names, scene.restored)]
        write_ply(root / scene_path.name, scene.gaussians)
        write_transforms_json(root / "cameras.json", scene.cameras)
        write_colmap_model(root / "colmap", scene.cameras, scene.geometry.points)
        write_preview_glb(root / "preview.glb", scene.gaussians, scene.cameras)
        for image in images:
            image.result()  # raises what the writing raised
        written_video = None
        if video is not None:
            if scene.view_source == "photo restoration" and len(scene.names) > 1:
                logger.warning("%s: an orbit of the network's scene, a ghosted overlay of the photos: no geometry "
                               "placed them (the restored views are the photos restored in 2D)", video)
            # as bright as the restored views: completed as they were (filled renders of the scene)
            filled = scene.fill_unobserved  # a one-photo scene's view is no render, but its orbit is one
            orbit = write_orbit_video(scene.gaussians, scene.cameras, staging.files[Path(video)],
                                      on_frame=on_video_frame, fill=filled)
            stream = probe_video(staging.files[Path(video)])  # as ffmpeg reads it back (H.264 pads odd sides)
            written_video = {"path": str(video), "codec": stream.codec, "pixel_format": stream.pixel_format,
                             "width": stream.width, "height": stream.height, "frames": len(orbit), "filled": filled}
        earlier_write = scene.timings.get("write", 0.0)  # a scene written twice counts its last write
        scene.timings["write"] = time.perf_counter() - started
        if "total" in scene.timings:
            scene.timings["total"] += scene.timings["write"] - earlier_write
        summary = finite_document(scene.summary(scene_path, (root / scene_path.name).stat().st_size)
                                  | {"video": written_video}, "summary.json")
        (root / "summary.json").write_text(json_text(summary))
    return summary
