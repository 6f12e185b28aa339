"""What training renders and scores: the fused Gaussians rendered at the predicted cameras (for the
loss and for validation), and the validation pass itself (one line of validation.jsonl and a
picture of input | render | target rows)."""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Iterable
from contextlib import AbstractContextManager
from pathlib import Path

import numpy as np
import torch

from lumos3d_cli.eval.metrics import psnr
from lumos3d_cli.eval.pose_accuracy import relative_pose_errors, summarise_pose_errors
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.image_write import write_image
from lumos3d_cli.io.json_text import finite_document
from lumos3d_cli.model.lumos3d import Lumos3D, Lumos3DOutput
from lumos3d_cli.render.render import render

logger = logging.getLogger(__name__)


def render_views(output: Lumos3DOutput, background: tuple[float, float, float]) -> tuple[torch.Tensor, torch.Tensor]:
    """Render every scene's fused Gaussians at its predicted cameras, at the network size:
    images [B, V, 3, H, W], expected depth [B, V, H, W]."""
    width, height = output.image_size
    images, depths = [], []
    for scene, gaussians in enumerate(output.gaussians):
        views = output.extrinsics.shape[1]
        cameras = Cameras(output.extrinsics[scene].detach(), output.intrinsics[scene].detach(), [(width, height)] * views)
        rendered = render(gaussians, cameras, background=background)
        images.append(rendered.images)
        depths.append(rendered.depths)
    return torch.stack(images), torch.stack(depths)


def validate(
    model: Lumos3D,
    samples: Iterable[tuple[dict[str, torch.Tensor], torch.Tensor, torch.Tensor]],
    step: int,
    output: Path,
    views: int,
    background: tuple[float, float, float],
    autocast: Callable[[], AbstractContextManager],
    extra: dict[str, float] | None = None,
) -> tuple[dict, Path]:
    """Score `samples` (batch of one sample, network input [1, V, 3, H, W], normal-light targets
    [1, V, 3, H, W]): PSNR of the renders against the targets and, for samples with dataset
    cameras, the accuracy of the predicted cameras (eval/pose_accuracy.py); append the line to
    output/validation.jsonl; write the first sample's first `views` views as rows of
    input | render | target to output/validation/step_<step>.png; return the line and the
    picture's path.
    `model` is left in eval mode; `autocast()` gives the run's precision context; `extra` scores
    (e.g. the held-out brackets') join the line.
    """
    model.eval()
    rotation_errors, translation_errors, psnrs = [], [], []
    first = None
    for batch, inputs, targets in samples:
        with torch.no_grad(), autocast():
            prediction = model(inputs)
        renders, _ = render_views(prediction, background)
        renders = renders.to(targets).clamp(0, 1)
        psnrs.append(float(psnr(renders[0], targets[0]).mean()))
        if bool(batch["has_poses"][0]) and inputs.shape[1] > 1:
            errors = relative_pose_errors(prediction.extrinsics[0].detach().double().cpu(), batch["extrinsics"][0].double().cpu())
            rotation_errors.append(errors[0])
            translation_errors.append(errors[1])
        if first is None:
            first = (inputs, renders, targets)
    line = {"step": step, "samples": len(psnrs), "psnr": float(np.mean(psnrs))}
    if rotation_errors:
        line["cameras"] = summarise_pose_errors(torch.cat(rotation_errors), torch.cat(translation_errors)).as_dict()
    line.update(extra or {})
    with open(output / "validation.jsonl", "a") as handle:
        handle.write(json.dumps(finite_document(line, "validation.jsonl"), allow_nan=False) + "\n")
    cameras = line.get("cameras")
    logger.info("validation at step %d: PSNR %.2f dB%s", step, line["psnr"],
                f", cameras AUC@30 {cameras['auc_30']:.3f}, rotation error median {cameras['rotation_error_median']:.1f}°"
                if cameras else "")
    inputs, renders, targets = first
    rows = [torch.cat([inputs[0, v], renders[0, v], targets[0, v]], dim=-1) for v in range(min(views, inputs.shape[1]))]
    grid = torch.cat(rows, dim=-2).permute(1, 2, 0).float().cpu().numpy()
    path = validation_picture(output, step)
    write_image(path, grid)
    return line, path


def validation_picture(output: Path, step: int) -> Path:
    """The picture of the validation after `step` steps in the run folder `output`."""
    return output / "validation" / f"step_{step:08d}.png"
