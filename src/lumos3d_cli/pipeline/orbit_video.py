"""An orbit of a restored scene as a video that plays everywhere (H.264 .mp4, or .gif)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.io.video import VideoWriter, video_kind
from lumos3d_cli.render.camera_paths import orbit_from_cameras
from lumos3d_cli.render.hole_filling import render_shown

# The CPU renderer's cost grows with the pixels: 512 wide keeps a 120-frame orbit to minutes
# while staying sharp on a laptop screen.
DEFAULT_ORBIT_WIDTH = 512
DEFAULT_ORBIT_FRAMES = 120


def orbit_size(cameras: Cameras, width: int) -> tuple[int, int]:
    """(width, height) with the first camera's aspect ratio, never wider than that camera."""
    native_width, native_height = cameras.sizes[0]
    width = min(width, native_width)
    return width, max(1, round(width * native_height / native_width))


def write_orbit_video(
    gaussians: Gaussians,
    cameras: Cameras,
    path: Path | str,
    frames: int = DEFAULT_ORBIT_FRAMES,
    fps: int = 30,
    width: int = DEFAULT_ORBIT_WIDTH,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    on_frame: Callable[[], None] | None = None,
    fill: bool = False,
) -> Cameras:
    """Render `frames` views on an orbit through the space `cameras` cover (see
    `render.camera_paths.orbit_from_cameras`) into `path` (.mp4 H.264 or .gif by suffix; a command
    writes it into its staging area, io/output_set.py). on_frame() runs after each frame
    (progress). With `fill` each frame is completed as the restored views are
    (render.hole_filling; `background` then does not apply). Returns the orbit's cameras."""
    kind = video_kind(path)
    if frames < 1:
        raise ValueError(f"an orbit video needs at least one frame, got {frames}")
    orbit = orbit_from_cameras(cameras, frames, *orbit_size(cameras, width), gaussians)
    frame_width, frame_height = orbit.sizes[0]
    with VideoWriter(path, frame_width, frame_height, fps, kind) as writer:
        for index in range(frames):
            image = render_shown(gaussians, orbit[index], fill, background).image  # [3, H, W]
            writer.write(image.permute(1, 2, 0).cpu().numpy())
            if on_frame is not None:
                on_frame()
    return orbit
