"""The render job: a Gaussian scene rendered from given cameras or along an orbit, written as PNG
frames and optionally a video (H.264 or GIF), all or nothing."""

from __future__ import annotations

import contextlib
import json
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError, listed
from lumos3d_cli.geometry.field_of_view import MEASURED_FOV_DEGREES, implausible_views
from lumos3d_cli.geometry.given_poses import centred_if_far
from lumos3d_cli.geometry.similarity import moved_to_origin
from lumos3d_cli.io.camera_files import camera_sources, find_camera_source, read_cameras
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.io.image_write import write_image
from lumos3d_cli.io.output_set import OutputSet
from lumos3d_cli.io.video import VideoWriter, probe_video, video_kind
from lumos3d_cli.pipeline.progress import JobProgress, SilentProgress
from lumos3d_cli.render.camera_paths import orbit_from_cameras, orbit_from_gaussians
from lumos3d_cli.render.clipping_range import require_drawable
from lumos3d_cli.render.constants import MAX_IMAGE_SIDE
from lumos3d_cli.render.hole_filling import render_shown

logger = logging.getLogger(__name__)

DEFAULT_ORBIT_SIZE = 512


def output_size(native: tuple[int, int], width: int | None, height: int | None) -> tuple[int, int]:
    """The requested (width, height); one side alone keeps the native aspect ratio."""
    for name, value in (("width", width), ("height", height)):
        if value is not None and not 1 <= value <= MAX_IMAGE_SIDE:
            raise InputError(f"{value}: use a size between 1 and {MAX_IMAGE_SIDE} pixels", parameter=name)
    if width and height:
        return width, height
    if width:
        size, given, name = (width, max(1, round(width * native[1] / native[0]))), width, "width"
    elif height:
        size, given, name = (max(1, round(height * native[0] / native[1])), height), height, "height"
    else:
        return native
    if max(size) > MAX_IMAGE_SIDE:  # the other side, from the aspect ratio: a 16x4000 camera at width 96 is 24000 tall
        raise InputError(f"{given}: makes {size[0]}x{size[1]} frames of a {native[0]}x{native[1]} camera, beyond {MAX_IMAGE_SIDE} "
                         "pixels a side; give a smaller size, or both width and height", parameter=name)
    return size


def camera_file_cameras(poses: Path, width: int | None = None, height: int | None = None) -> tuple[Cameras, str]:
    """The cameras of the camera file `poses` at the frame size asked for (each at its own size, or
    with one side given each keeping its aspect ratio), and where they came from. It needs no
    scene: `render` reads it before the scene."""
    cameras, source = read_cameras(poses), str(find_camera_source(poses))
    odd = implausible_views(cameras.intrinsics, cameras.sizes)
    if odd:  # at a focal length of 1e13 px the frames came out black without a word
        logger.warning("%s: %d camera(s) with a field of view no lens has (%s; lenses see %g to %g degrees): their "
                       "frames may not show the scene", source, len(odd),
                       listed([f"{cameras.names[view] or view}: {degrees:.3g} degrees" for view, degrees in odd.items()], 3),
                       *MEASURED_FOV_DEGREES)
    if width is not None or height is not None:  # each camera keeps its own aspect ratio (photos may differ)
        cameras = cameras.rescaled_to([output_size(size, width, height) for size in cameras.sizes])
    too_large = [f"{name or index} ({w}x{h})" for index, (name, (w, h)) in enumerate(zip(cameras.names, cameras.sizes))
                 if max(w, h) > MAX_IMAGE_SIDE]  # its own size, or the side computed from the one given
    if too_large:
        raise InputError(f"{source}: frames larger than {MAX_IMAGE_SIDE} pixels a side: {listed(too_large, 3)}; give a "
                         "smaller width or height", parameter="poses")
    return cameras, source


def render_cameras(
    scene: Path, gaussians: Gaussians, poses: Path | None = None, orbit: int | None = None,
    width: int | None = None, height: int | None = None,
) -> tuple[Cameras, str]:
    """The cameras to render `gaussians` (read from `scene`) from, and where they came from: the
    camera file `poses` (`camera_file_cameras`), or `orbit` frames around the cameras beside the
    scene (a restore output) or, without any, around the scene's bounds."""
    if (poses is None) == (orbit is None):
        raise InputError("give exactly one of poses (a camera file) or orbit (a frame count)", parameter="poses")
    if poses is not None:
        return camera_file_cameras(poses, width, height)
    passed_over = 0
    for nearby in camera_sources(scene.parent):  # the first that can be read (a broken one is passed over)
        try:
            # a dataset's own far poses (sparse/0 beside a scene restore centred on them) in its frame
            scene_cameras = onto_restored_scene(scene, gaussians, read_cameras(nearby))
        except InputError as error:  # a file the user did not name: not a reason to refuse the orbit
            logger.warning("%s; passed over for the orbit", error)
            passed_over += 1
            continue
        size = output_size(scene_cameras.sizes[0], width, height)
        return orbit_from_cameras(scene_cameras, orbit, *size, gaussians), f"orbit around the cameras in {nearby}"
    readable = "no camera file beside it can be read" if passed_over else "it has no cameras beside it"
    if len(gaussians) == 0:
        raise InputError(f"{scene}: the scene is empty and {readable}; give poses", parameter="scene")
    if passed_over:
        logger.warning("%s: %s; orbiting around the scene's bounds instead", scene, readable)
    size = output_size((DEFAULT_ORBIT_SIZE,) * 2, width, height)
    return orbit_from_gaussians(gaussians, orbit, *size), "orbit around the scene bounds"


def in_rendering_frame(scene: Path, gaussians: Gaussians, cameras: Cameras) -> tuple[Gaussians, Cameras]:
    """The Gaussians read from `scene` and the cameras to render them from, in a frame the
    renderer's float32 holds: the cameras first moved onto a restored scene that was centred on its
    far poses (`onto_restored_scene`), then, where they still lie far from the origin
    (`centred_if_far`), both moved to the cameras' mean centre (in float64)."""
    cameras = onto_restored_scene(scene, gaussians, cameras)
    moved, centre = centred_if_far(cameras)
    if centre is None:
        return gaussians, cameras
    means = (gaussians.means.double() - centre.to(gaussians.means.device)).to(gaussians.means.dtype)
    return replace(gaussians, means=means), moved


def onto_restored_scene(scene: Path, gaussians: Gaussians, cameras: Cameras) -> Cameras:
    """`cameras` in the frame of the scene `scene` holds: when its restore centred it on far poses
    (summary.json beside it records `geometry.poses_origin`) and the cameras are in the poses' own
    frame (moved by that origin they lie nearer the scene's Gaussians, as judged by the median of
    their means), moved by it; else as they are (already the scene's: its cameras.json, an orbit)."""
    origin = _restore_origin(scene)
    if origin is None or len(gaussians) == 0:
        return cameras
    middle = gaussians.means.detach().double().cpu().median(dim=0).values
    centres = cameras.centers().double().cpu()
    moved = centres - origin
    if float((moved - middle).norm(dim=1).median()) >= float((centres - middle).norm(dim=1).median()):
        return cameras
    logger.info("%s: the scene was centred on its poses by restore; the cameras are moved by the same %s",
                scene, origin.tolist())
    return moved_to_origin(cameras, origin)


def _restore_origin(scene: Path) -> torch.Tensor | None:
    """summary.json's `geometry.poses_origin` [3] (float64) beside `scene`, when that summary is
    the scene's restore's and records one; else None."""
    try:
        summary = json.loads((scene.parent / "summary.json").read_text())
        origin = summary["geometry"]["poses_origin"]
        named = Path(summary["scene"]).name
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if named != scene.name or not (isinstance(origin, list) and len(origin) == 3 and all(
            isinstance(value, (int, float)) and math.isfinite(value) for value in origin)):
        return None
    return torch.tensor(origin, dtype=torch.float64)


@dataclass
class RenderedFrames:
    """frames written, their size (width, height; the first frame's when sizes differ) and every
    size they have (in the order first met), milliseconds per rendered frame, and the video as
    ffmpeg reads it back (None without one)."""

    frames: int
    sizes: list[tuple[int, int]]
    render_ms_per_frame: float
    video: dict | None

    @property
    def size(self) -> tuple[int, int]:
        return self.sizes[0]


def render_outputs(frames: int, output: Path, video: Path | None = None, inputs: Sequence[Path | None] = ()) -> OutputSet:
    """The outputs of a render: `frames` PNGs in `output` (an earlier render's other frames there
    go) and `video`, kept clear of `inputs` (the scene, the camera file)."""
    outputs = OutputSet(output, "render", "render", inputs)
    for index in range(frames):
        outputs.add_file(f"{index:05d}.png")
    if video is not None:
        outputs.add_elsewhere(video, f"video {video.name}")
    return outputs


def render_frames(
    gaussians: Gaussians, cameras: Cameras, output: Path, video: Path | None = None, fps: int = 30,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0), antialiased: bool = False,
    progress: JobProgress | None = None, inputs: Sequence[Path | None] = (), scene_name: str | None = None,
    fill: bool = False,
) -> RenderedFrames:
    """Render every camera, each at its own size, into `output`/00000.png ... (and `video`, .mp4 or
    .gif, whose frames share the first camera's size); the folder's frames and the video appear
    when all are written, never over a file lumos3d did not write nor over `inputs`
    (io/output_set.py). A scene no camera can draw (render.clipping_range) is refused, naming
    `scene_name` (its file) when given. With `fill` each frame is completed as restore's views
    are (render.hole_filling: covered pixels divided by their alpha, the uncovered inpainted), and
    `background` does not apply."""
    progress = progress or SilentProgress()
    kind = video_kind(video) if video is not None else None
    if len(gaussians) == 0:
        raise InputError("holds no Gaussians: there is nothing to render", parameter="scene")
    require_drawable(gaussians.means, cameras, scene_name)  # a scene in extreme units would render black
    if video is not None and len(set(cameras.sizes)) > 1:
        logger.warning("the cameras have %d different image sizes; a video has one: every frame is rendered at %dx%d",
                       len(set(cameras.sizes)), *cameras.sizes[0])
        cameras = cameras.rescaled(*cameras.sizes[0])
    frame_width, frame_height = cameras.sizes[0]
    render_seconds = 0.0
    progress.start("render", len(cameras))
    with render_outputs(len(cameras), output, video, inputs).staged() as staging:
        with (VideoWriter(staging.files[video], frame_width, frame_height, fps, kind)
              if video is not None else contextlib.nullcontext()) as writer:
            for index in range(len(cameras)):
                started = time.perf_counter()
                image = render_shown(gaussians, cameras[index], fill, background, antialiased=antialiased).image
                render_seconds += time.perf_counter() - started
                pixels = image.permute(1, 2, 0).numpy()
                write_image(staging.root / f"{index:05d}.png", pixels)
                if writer is not None:
                    writer.write(pixels)
                progress.advance("render")
    written = None
    if video is not None:
        # What the file holds as ffmpeg reads it back (H.264 pads odd sides).
        stream = probe_video(video)
        written = {"path": str(video), "codec": stream.codec, "pixel_format": stream.pixel_format,
                   "width": stream.width, "height": stream.height, "frames": len(cameras), "fps": fps}
    return RenderedFrames(len(cameras), list(dict.fromkeys(cameras.sizes)), round(1000 * render_seconds / len(cameras), 2),
                          written)
