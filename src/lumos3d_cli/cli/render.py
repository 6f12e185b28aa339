"""`lumos3d render`: render a Gaussian scene from given cameras or an orbit, to PNGs and a video
(H.264 .mp4 or .gif)."""

from __future__ import annotations

import contextlib
import time
from pathlib import Path

import torch
import typer

from lumos3d_cli.cli.console import print_json, progress_bar, say
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import atomic_directory, atomic_path
from lumos3d_cli.io.camera_files import find_camera_source, read_cameras
from lumos3d_cli.io.image_write import write_image
from lumos3d_cli.io.output_paths import check_output_path
from lumos3d_cli.io.ply import read_ply
from lumos3d_cli.io.video import VideoWriter, probe_video, video_kind
from lumos3d_cli.render.camera_paths import orbit_from_cameras, orbit_from_gaussians
from lumos3d_cli.render.render import render

EXAMPLES = """
  lumos3d render out/scene.ply --orbit 60 -o frames/ --video orbit.mp4
  lumos3d render scene.ply --poses cameras.json -o views/ --width 1024
  lumos3d render scene.ply --poses sparse/0 -o views/ --background 1,1,1 --json
  lumos3d render out/scene.ply --orbit 48 -o frames/ --video orbit.gif --fps 12 --width 320
"""

_DEFAULT_ORBIT_SIZE = 512


def parse_background(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise InputError(f"--background {text!r}: give three numbers in [0, 1] separated by commas, e.g. 1,1,1")
    return values  # type: ignore[return-value]


def _output_size(native: tuple[int, int], width: int | None, height: int | None) -> tuple[int, int]:
    """The requested size; one side alone keeps the native aspect ratio."""
    for name, value in (("--width", width), ("--height", height)):
        if value is not None and not 1 <= value <= 16384:
            raise InputError(f"{name} {value}: use a size between 1 and 16384 pixels")
    if width and height:
        return width, height
    if width:
        return width, max(1, round(width * native[1] / native[0]))
    if height:
        return max(1, round(height * native[0] / native[1])), height
    return native


def _video_summary(path: Path, frames: int, fps: int) -> dict:
    """What the written video holds, as ffmpeg reads it back (codec and size may differ from the
    frames': H.264 pads odd sides)."""
    stream = probe_video(path)
    return {"path": str(path), "codec": stream.codec, "pixel_format": stream.pixel_format,
            "width": stream.width, "height": stream.height, "frames": frames, "fps": fps}


def render_command(
    scene: Path = typer.Argument(..., help="Gaussian scene (.ply, INRIA 3DGS layout)."),
    output: Path = typer.Option(..., "--output", "-o", help="Folder for the rendered PNGs."),
    poses: Path | None = typer.Option(None, "--poses", help="Cameras: transforms.json/cameras.json or a COLMAP text folder."),
    orbit: int | None = typer.Option(None, "--orbit", help="Render N frames on an orbit around the scene."),
    width: int | None = typer.Option(None, "--width", help="Output width (default: the cameras', or 512 for orbits without cameras)."),
    height: int | None = typer.Option(None, "--height", help="Output height."),
    video: Path | None = typer.Option(None, "--video", help="Also write the frames as a video: .mp4 (H.264, plays in browsers) or .gif."),
    fps: int = typer.Option(30, "--fps", help="Frames per second of the video."),
    background: str = typer.Option("0,0,0", "--background", help="Background colour r,g,b in [0, 1]."),
    antialiased: bool = typer.Option(False, "--antialiased", help="Mip-Splatting 2D filter (opacity compensation)."),
    json_output: bool = typer.Option(False, "--json", help="Print a JSON summary on stdout."),
) -> None:
    """Render a Gaussian scene from cameras or along an orbit."""
    if (poses is None) == (orbit is None):
        raise InputError("give exactly one of --poses CAMERAS or --orbit N")
    if orbit is not None and not 1 <= orbit <= 100000:
        raise InputError(f"--orbit {orbit}: use between 1 and 100000 frames")
    kind = video_kind(video) if video is not None else None
    if not 1 <= fps <= 240:
        raise InputError(f"--fps {fps}: use between 1 and 240")
    colour = parse_background(background)
    check_output_path(output, "output", folder=True)
    check_output_path(video, "video")
    gaussians = read_ply(scene)
    if poses is not None:
        cameras = read_cameras(poses)
        cameras = cameras.rescaled(*_output_size(cameras.sizes[0], width, height))
        source = str(find_camera_source(poses))
    else:
        nearby = find_camera_source(scene.parent)
        if nearby is not None:
            scene_cameras = read_cameras(nearby)
            cameras = orbit_from_cameras(scene_cameras, orbit, *_output_size(scene_cameras.sizes[0], width, height), gaussians)
            source = f"orbit around the cameras in {nearby}"
        else:
            if len(gaussians) == 0:
                raise InputError(f"{scene}: the scene is empty and has no cameras beside it; pass --poses")
            cameras = orbit_from_gaussians(gaussians, orbit, *_output_size((_DEFAULT_ORBIT_SIZE,) * 2, width, height))
            source = "orbit around the scene bounds"
    frame_width, frame_height = cameras.sizes[0]
    started = time.perf_counter()
    render_seconds = 0.0
    with atomic_directory(output) as staging, progress_bar() as progress:
        task = progress.add_task("render", total=len(cameras))
        with atomic_path(video) if video is not None else contextlib.nullcontext() as video_temporary:
            with (VideoWriter(video_temporary, frame_width, frame_height, fps, kind)
                  if video_temporary is not None else contextlib.nullcontext()) as writer:
                for index in range(len(cameras)):
                    frame_started = time.perf_counter()
                    with torch.no_grad():
                        image = render(gaussians, cameras[index], background=colour, antialiased=antialiased).images[0]
                    render_seconds += time.perf_counter() - frame_started
                    pixels = image.permute(1, 2, 0).numpy()
                    write_image(staging / f"{index:05d}.png", pixels)
                    if writer is not None:
                        writer.write(pixels)
                    progress.advance(task)
    summary = {
        "scene": str(scene), "gaussians": len(gaussians), "sh_degree": gaussians.sh_degree,
        "cameras": source, "frames": len(cameras), "width": frame_width, "height": frame_height,
        "output": str(output), "video": _video_summary(video, len(cameras), fps) if video else None,
        "render_ms_per_frame": round(1000 * render_seconds / len(cameras), 2),
        "total_seconds": round(time.perf_counter() - started, 3),
    }
    if json_output:
        print_json(summary)
    else:
        say(f"wrote {len(cameras)} frame(s) of {frame_width}x{frame_height} to {output}" + (f" and {video}" if video else ""))

