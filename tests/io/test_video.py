import subprocess
import sys

import imageio_ffmpeg
import numpy as np
import pytest

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.video import VideoWriter, probe_video, video_frame_size, video_kind


def write_video(path, frames, fps: float = 30.0) -> int:
    """Write frames [H, W, 3] (float sRGB in [0, 1] or uint8; at least one) through VideoWriter, the
    container from the suffix; returns the number written."""
    iterator = iter(frames)
    first = next(iterator)
    with VideoWriter(path, first.shape[1], first.shape[0], fps, video_kind(path)) as writer:
        writer.write(first)
        for frame in iterator:
            writer.write(frame)
    return writer.frames


def _frames(count: int, width: int, height: int) -> list[np.ndarray]:
    """Smooth gradients that move, [H, W, 3] float in [0, 1]: what rendered scenes look like to a codec."""
    y, x = np.mgrid[0:height, 0:width] / max(width, height)
    return [np.stack([(x + 0.1 * i) % 1, y, 0.5 + 0.4 * np.sin(6 * x + i)], axis=-1) for i in range(count)]


def _read_back(path, width: int, height: int) -> tuple[dict, list[np.ndarray]]:
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    frames = [np.frombuffer(raw, np.uint8).reshape(height, width, 3) for raw in reader]
    return meta, frames


def test_mp4_is_h264_yuv420p_with_every_frame(tmp_path):
    frames = _frames(9, 64, 48)
    assert write_video(tmp_path / "a.mp4", frames, fps=12) == 9
    stream = probe_video(tmp_path / "a.mp4")
    assert (stream.codec, stream.pixel_format, stream.width, stream.height) == ("h264", "yuv420p", 64, 48)
    meta, decoded = _read_back(tmp_path / "a.mp4", 64, 48)
    assert meta["codec"] == "h264" and meta["fps"] == 12 and len(decoded) == 9
    for original, back in zip(frames, decoded):
        assert np.abs(back / 255.0 - original).mean() < 0.02


def test_odd_sizes_are_padded_to_even_for_h264(tmp_path):
    assert video_frame_size(33, 21) == (34, 22) and video_frame_size(32, 20) == (32, 20)
    frames = _frames(2, 33, 21)
    write_video(tmp_path / "odd.mp4", frames)
    stream = probe_video(tmp_path / "odd.mp4")
    assert (stream.width, stream.height) == (34, 22)
    _, decoded = _read_back(tmp_path / "odd.mp4", 34, 22)
    # The added column and row repeat the edge, not black.
    assert np.abs(decoded[0][:21, 33] / 255.0 - frames[0][:, 32]).mean() < 0.05


def test_gif_keeps_the_size_and_the_frames(tmp_path):
    frames = _frames(4, 33, 21)
    assert write_video(tmp_path / "a.gif", [np.round(f * 255).astype(np.uint8) for f in frames], fps=10) == 4
    stream = probe_video(tmp_path / "a.gif")
    assert (stream.codec, stream.width, stream.height) == ("gif", 33, 21)
    assert imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "a.gif"))[0] == 4
    _, decoded = _read_back(tmp_path / "a.gif", 33, 21)
    assert np.abs(decoded[0] / 255.0 - frames[0]).mean() < 0.03  # one 256-colour palette per clip


def test_the_container_comes_from_kind_not_the_name(tmp_path):
    with VideoWriter(tmp_path / "temporary.tmp", 16, 16, 5, "mp4") as writer:
        writer.write(np.zeros((16, 16, 3), np.uint8))
    assert probe_video(tmp_path / "temporary.tmp").codec == "h264"


def test_bad_inputs(tmp_path):
    with pytest.raises(InputError, match=r"^video clip\.avi: the file name must end in \.mp4"):
        video_kind("clip.avi")
    assert video_kind("A.MP4") == "mp4" and video_kind("b.gif") == "gif"
    with pytest.raises(InputError, match="missing.mp4: no such video file"):
        probe_video(tmp_path / "missing.mp4")
    (tmp_path / "text.mp4").write_text("not a video")
    with pytest.raises(InputError, match="text.mp4: ffmpeg finds no video stream"):
        probe_video(tmp_path / "text.mp4")
    with VideoWriter(tmp_path / "b.mp4", 16, 16, 5) as writer:
        with pytest.raises(ValueError, match="frame of 8x16 in a 16x16 video"):
            writer.write(np.zeros((16, 8, 3), np.uint8))
        writer.write(np.zeros((16, 16, 3), np.uint8))


def test_a_writer_stopped_while_ffmpeg_starts_ends_ffmpeg(monkeypatch, tmp_path):
    """A signal while ffmpeg starts (before a `with` block could close the writer) must not leave
    ffmpeg running to write its file again after the cleanup removed it: the writer closes
    imageio-ffmpeg's generator, whose cleanup ends ffmpeg."""
    from lumos3d_cli.errors import Interrupted

    class StoppedWhileStarting:
        closed = False

        def send(self, value):
            raise Interrupted(15)

        def close(self):
            self.closed = True

    started = StoppedWhileStarting()
    monkeypatch.setattr(imageio_ffmpeg, "write_frames", lambda *args, **kwargs: started)
    with pytest.raises(Interrupted):
        VideoWriter(tmp_path / "a.mp4", 16, 16, 5)
    assert started.closed


def test_a_restore_that_writes_no_video_runs_without_imageio_ffmpeg():
    # The ffmpeg wheel is 68 MB and machines without a package index (a GPU box) may lack it:
    # the modules a photo restore imports, and naming a video file, must not need it.
    code = (
        "import sys; sys.modules['imageio_ffmpeg'] = None\n"
        "import lumos3d_cli.cli.restore, lumos3d_cli.cli.render, lumos3d_cli.pipeline.restore_outputs\n"
        "from lumos3d_cli.io.video import VideoWriter, video_kind\n"
        "print(video_kind('orbit.gif'))\n"
        "try:\n"
        "    VideoWriter('x.mp4', 4, 4, 1.0)\n"
        "except ImportError:\n"
        "    print('needed to write')\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.split() == ["gif", "needed", "to", "write"]
