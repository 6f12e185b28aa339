"""Videos that play everywhere: H.264 in MP4 (yuv420p, browsers and phones) or an animated GIF,
encoded by the ffmpeg binary that the imageio-ffmpeg wheel ships (no system ffmpeg needed)."""

from __future__ import annotations

import re
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lumos3d_cli.errors import InputError

VIDEO_SUFFIXES = (".mp4", ".gif")

# x264's constant-quality scale: 18 is visually lossless on rendered scenes at about a third of
# the bytes of crf 12; "medium" is x264's default speed/size balance.
_H264_CRF = 18
_H264_PRESET = "medium"
# One palette computed over the whole clip (palettegen) instead of ffmpeg's fixed 256-colour
# palette: smooth shading bands badly without it.
_GIF_FILTER = "split[frames][copy];[copy]palettegen=stats_mode=diff[palette];[frames][palette]paletteuse=dither=sierra2_4a"


def video_frame_size(width: int, height: int) -> tuple[int, int]:
    """The size a video of width x height frames gets: yuv420p stores colour at half resolution,
    so H.264 needs even sides; an odd side gains one replicated pixel row/column."""
    return width + width % 2, height + height % 2


def to_video_frame(frame: np.ndarray, even: bool = True) -> np.ndarray:
    """[H, W, 3] float sRGB in [0, 1] or uint8 -> [H', W', 3] uint8 (H', W' even when `even`)."""
    if frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(f"a video frame has shape (H, W, 3), got {frame.shape}")
    if frame.dtype != np.uint8:
        frame = np.round(np.clip(frame, 0.0, 1.0) * 255).astype(np.uint8)
    height, width = frame.shape[:2]
    if not even:
        return np.ascontiguousarray(frame)
    padded_width, padded_height = video_frame_size(width, height)
    if (padded_width, padded_height) != (width, height):
        frame = np.pad(frame, ((0, padded_height - height), (0, padded_width - width), (0, 0)), mode="edge")
    return np.ascontiguousarray(frame)


class VideoWriter:
    """Stream frames into an .mp4 (H.264, yuv420p, +faststart) or a .gif.

    The container comes from `kind` ("mp4" or "gif"), not from the file name, so a temporary
    name (see io.atomic) works. Use as a context manager; frames are [H, W, 3] (see
    `to_video_frame`) and must all have the size given here.
    """

    def __init__(self, path: Path | str, width: int, height: int, fps: float, kind: str = "mp4") -> None:
        if kind not in ("mp4", "gif"):
            raise ValueError(f"video kind {kind!r}: use mp4 or gif")
        self.path = Path(path)
        self.size = (width, height)
        self.frames = 0
        # GIF stores full-resolution palette indices: any size goes.
        self._even = kind == "mp4"
        padded = video_frame_size(width, height) if self._even else (width, height)
        if kind == "mp4":
            options = {
                "codec": "libx264", "pix_fmt_out": "yuv420p",
                "output_params": [
                    "-crf", str(_H264_CRF), "-preset", _H264_PRESET,
                    # Convert with the BT.709 matrix and say so: players guess the matrix of an
                    # untagged stream (BT.601 or 709 by size) and shift colours when they guess wrong.
                    "-vf", "scale=out_color_matrix=bt709:out_range=tv,"
                    "setparams=color_primaries=bt709:color_trc=bt709:colorspace=bt709",
                    # Browsers start playing before the whole file arrives only with the index up front.
                    "-movflags", "+faststart", "-f", "mp4",
                ],
            }
        else:
            options = {"codec": "gif", "pix_fmt_out": "pal8", "output_params": ["-filter_complex", _GIF_FILTER, "-f", "gif"]}
        # quality=None: the rate control is in output_params; macro_block_size=1: H.264 frames are
        # padded to even sides here rather than rescaled by imageio-ffmpeg.
        # Imported here, not at the top: a restore or render that writes no video must run where the
        # 68 MB wheel with ffmpeg is not installed (a GPU machine without an index, say).
        import imageio_ffmpeg

        self._generator = imageio_ffmpeg.write_frames(
            str(self.path), padded, fps=fps, quality=None, macro_block_size=1, ffmpeg_log_level="error", **options
        )
        try:
            self._generator.send(None)  # starts ffmpeg
        except BaseException:
            # Stopped (a signal) while ffmpeg starts, before any `with` block can close it: end it
            # here, or it outlives the cleanup that removes its file and writes that file again.
            self._generator.close()
            raise

    def write(self, frame: np.ndarray) -> None:
        """Append one [H, W, 3] frame."""
        if frame.shape[:2] != (self.size[1], self.size[0]):
            raise ValueError(f"frame of {frame.shape[1]}x{frame.shape[0]} in a {self.size[0]}x{self.size[1]} video")
        self._generator.send(to_video_frame(frame, self._even))
        self.frames += 1

    def close(self) -> None:
        """Finish the file (ffmpeg writes the index and exits)."""
        self._generator.close()

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, *_) -> None:
        self.close()


def video_kind(path: Path | str, parameter: str = "video") -> str:
    """"mp4" or "gif" from the file name; InputError (naming `parameter`) for anything else."""
    suffix = Path(path).suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise InputError(f"{path}: the file name must end in .mp4 (H.264) or .gif", parameter=parameter)
    return suffix[1:]


@dataclass(frozen=True)
class VideoStream:
    """What ffmpeg reports about a file's first video stream."""

    codec: str  # e.g. "h264", "gif"
    pixel_format: str  # e.g. "yuv420p"
    width: int
    height: int


# "Stream #0:0[0x1](und): Video: h264 (High) (avc1 / 0x31637661), yuv420p(progressive), 64x48 ..."
_STREAM_LINE = re.compile(r"Stream #\d+:\d+.*?: Video: (?P<codec>\w+)[^,]*, (?P<pixfmt>\w+)(?:\([^)]*\))?,.*? (?P<w>\d+)x(?P<h>\d+)")


def probe_video(path: Path | str) -> VideoStream:
    """Codec, pixel format and size of `path`'s video stream, read by the bundled ffmpeg."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such video file")
    import imageio_ffmpeg  # see VideoWriter

    # `ffmpeg -i` without an output prints the stream table on stderr and exits 1 by design.
    result = subprocess.run(
        [imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)], capture_output=True, text=True, check=False
    )
    match = _STREAM_LINE.search(result.stderr)
    if match is None:
        raise InputError(f"{path}: ffmpeg finds no video stream in it; is it a video file?")
    return VideoStream(match["codec"], match["pixfmt"], int(match["w"]), int(match["h"]))
