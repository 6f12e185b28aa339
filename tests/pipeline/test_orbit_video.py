import imageio_ffmpeg
import numpy as np
import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.video import probe_video
from lumos3d_cli.render.camera_paths import orbit_from_gaussians
from lumos3d_cli.render.render import render
from lumos3d_cli.pipeline.orbit_video import orbit_size, write_orbit_video

from factories import random_scene


def test_orbit_video_is_h264_with_the_rendered_frames(tmp_path):
    gaussians = random_scene(300, 0, degree=1, dtype=torch.float32, spread=0.4)
    cameras = orbit_from_gaussians(gaussians, 4, 66, 50)
    ticks = []
    orbit = write_orbit_video(gaussians, cameras, tmp_path / "orbit.mp4", frames=5, fps=10, width=33,
                              on_frame=lambda: ticks.append(1))
    assert len(ticks) == 5 and len(orbit) == 5 and orbit.sizes[0] == (33, 25)
    stream = probe_video(tmp_path / "orbit.mp4")
    assert (stream.codec, stream.pixel_format, stream.width, stream.height) == ("h264", "yuv420p", 34, 26)
    assert imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "orbit.mp4"))[0] == 5
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "orbit.mp4"))
    next(reader)
    first = np.frombuffer(next(reader), np.uint8).reshape(26, 34, 3)[:25, :33] / 255.0
    reader.close()
    expected = render(gaussians, orbit[0]).images[0].permute(1, 2, 0).numpy()
    assert np.abs(first.reshape(-1, 3).mean(0) - expected.reshape(-1, 3).mean(0)).max() < 0.02
    assert [p.name for p in tmp_path.iterdir()] == ["orbit.mp4"]  # no temporary left


def test_a_filled_orbit_is_as_bright_as_the_filled_views(tmp_path):
    """restore's video of a scene whose views are filled renders: each frame completed as they are
    (render.hole_filling), not the darker render over black."""
    from lumos3d_cli.render.hole_filling import fill_unobserved

    gaussians = random_scene(300, 0, degree=0, dtype=torch.float32, spread=0.4)
    gaussians.opacities = gaussians.opacities * 0.5  # half transparent: the fill brightens every covered pixel
    cameras = orbit_from_gaussians(gaussians, 4, 66, 50)
    orbit = write_orbit_video(gaussians, cameras, tmp_path / "orbit.mp4", frames=3, fps=10, width=33, fill=True)
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "orbit.mp4"))
    next(reader)
    first = np.frombuffer(next(reader), np.uint8).reshape(26, 34, 3)[:25, :33] / 255.0
    reader.close()
    rendered = render(gaussians, orbit[0])
    filled = fill_unobserved(rendered.images[0], rendered.alphas[0]).image.permute(1, 2, 0).numpy()
    plain = rendered.images[0].permute(1, 2, 0).numpy()
    assert abs(first.mean() - filled.mean()) < 0.02 and filled.mean() > plain.mean() + 0.05


def test_orbit_size_and_bad_inputs(tmp_path):
    cameras = orbit_from_gaussians(random_scene(10, 0), 2, 400, 300)
    assert orbit_size(cameras, 200) == (200, 150) and orbit_size(cameras, 1000) == (400, 300)
    with pytest.raises(InputError, match="orbit.avi"):
        write_orbit_video(random_scene(10, 0), cameras, tmp_path / "orbit.avi")
    assert not list(tmp_path.iterdir())
