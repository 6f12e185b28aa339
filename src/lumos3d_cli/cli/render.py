"""`lumos3d render`: render a Gaussian scene from given cameras or an orbit, to PNGs and a video
(H.264 .mp4 or .gif). The job is `pipeline.render_job`; this module parses, shows and prints."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import typer

from lumos3d_cli.cli.console import ProgressBars, print_json, progress_bar, say
from lumos3d_cli.cli.interrupts import library_imports
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.output_paths import check_output_path

MAX_GIF_FPS = 50  # a GIF frame lasts a whole number of hundredths of a second; browsers show no less than 2

EXAMPLES = """
  lumos3d render out/scene.ply --orbit 60 -o frames/ --video orbit.mp4
  lumos3d render scene.ply --poses cameras.json -o views/ --width 1024
  lumos3d render scene.ply --poses sparse/0 -o views/ --background 1,1,1 --json
  lumos3d render out/scene.ply --orbit 48 -o frames/ --video orbit.gif --fps 12 --width 320
  lumos3d render out/scene.ply --poses out/cameras.json -o views/ --fill-unobserved   [dim]# as restored/ shows them[/dim]
"""

def parse_background(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise InputError(f"--background {text!r}: give three numbers in [0, 1] separated by commas, e.g. 1,1,1")
    return values  # type: ignore[return-value]


def render_command(
    scene: Path = typer.Argument(..., help="Gaussian scene (.ply, INRIA 3DGS layout)."),
    output: Path = typer.Option(..., "--output", "-o", help="Folder for the rendered PNGs."),
    poses: Path | None = typer.Option(None, "--poses", help="Cameras: transforms.json/cameras.json, a LOM folder of transforms_*.json, or a COLMAP model folder (text or binary)."),
    orbit: int | None = typer.Option(None, "--orbit", help="Render N frames on an orbit around the scene."),
    width: int | None = typer.Option(None, "--width", help="Output width (default: the cameras', or 512 for orbits without cameras)."),
    height: int | None = typer.Option(None, "--height", help="Output height."),
    video: Path | None = typer.Option(None, "--video", help="Also write the frames as a video: .mp4 (H.264, plays in browsers) or .gif."),
    fps: int = typer.Option(30, "--fps", help="Frames per second of the video."),
    background: str = typer.Option("0,0,0", "--background", help="Background colour r,g,b in [0, 1]."),
    antialiased: bool = typer.Option(False, "--antialiased", help="Mip-Splatting 2D filter (opacity compensation)."),
    fill: bool = typer.Option(False, "--fill-unobserved/--black-unobserved",
                              help="Complete each frame as restore's views are (covered pixels divided by their alpha, "
                                   "uncovered ones inpainted), or draw it plainly over the background."),
    json_output: bool = typer.Option(False, "--json", help="Print a JSON summary on stdout."),
) -> None:
    """Render a Gaussian scene from cameras or along an orbit."""
    # The job imports torch, numba's kernels, pycolmap and imageio-ffmpeg (seconds): imported
    # here, when the command runs, so that `--help` stays fast.
    with library_imports():
        from lumos3d_cli.io.ply import read_ply
        from lumos3d_cli.io.video import video_kind
        from lumos3d_cli.pipeline.render_job import (
            camera_file_cameras, in_rendering_frame, output_size, render_cameras, render_frames, render_outputs,
        )
    if (poses is None) == (orbit is None):
        raise InputError("give exactly one of --poses CAMERAS or --orbit N")
    if orbit is not None and not 1 <= orbit <= 100000:
        raise InputError(f"--orbit {orbit}: use between 1 and 100000 frames")
    if not 1 <= fps <= 240:
        raise InputError(f"--fps {fps}: use between 1 and 240")
    if video is not None and video_kind(video) == "gif" and fps > MAX_GIF_FPS:
        logging.getLogger(__name__).warning(
            "--fps %d: a GIF holds frame times in hundredths of a second and browsers slow frames under 20 ms down to "
            "100 ms: it plays at most %d frames a second; use .mp4 for more", fps, MAX_GIF_FPS)
    output_size((1, 1), width, height)  # the sizes are checked before the scene is read (seconds for a large one)
    colour = parse_background(background)
    if fill and colour != (0.0, 0.0, 0.0):
        raise InputError(f"--background {background}: a filled frame shows no background; leave one of them out")
    check_output_path(output, "output", folder=True)
    check_output_path(video, "video")
    if video is not None and video.resolve() == output.resolve():
        raise InputError(f"--video {video}: is the frames' folder -o as well; give the video another path")
    # a camera file is read (and refused) before the scene, which takes seconds when large
    from_file = camera_file_cameras(poses, width, height) if poses is not None else None
    started = time.perf_counter()
    gaussians = read_ply(scene)
    if len(gaussians) == 0:
        raise InputError(f"{scene}: holds no Gaussians; there is nothing to render")
    cameras, source = from_file if from_file is not None else render_cameras(scene, gaussians, None, orbit, width, height)
    gaussians, cameras = in_rendering_frame(scene, gaussians, cameras)
    outputs = render_outputs(len(cameras), output, video, [scene, poses])
    with outputs.reserved(), progress_bar() as bars:
        frames = render_frames(gaussians, cameras, output, video, fps, colour, antialiased, ProgressBars(bars), [scene, poses],
                               str(scene), fill)
    summary = {
        "scene": str(scene), "gaussians": len(gaussians), "sh_degree": gaussians.sh_degree,
        "cameras": source, "frames": frames.frames, "width": frames.size[0], "height": frames.size[1],
        "sizes": [list(size) for size in frames.sizes],  # every frame's size (width and height: the first's)
        "output": str(output), "video": frames.video, "filled": fill, "render_ms_per_frame": frames.render_ms_per_frame,
        "total_seconds": round(time.perf_counter() - started, 3),
    }
    if json_output:
        print_json(summary)
    else:
        shapes = ", ".join(f"{w}x{h}" for w, h in frames.sizes)
        say(f"wrote {frames.frames} frame(s) of {shapes} to {output}" + (f" and {video}" if video else ""))
