"""Structure-from-motion started before torch is imported.

Where structure-from-motion sees the photos through the blind tone curve (a preset's
`sfm_brightening` "tone curve": `fast`), it needs nothing from the network, so `lumos3d restore`
starts it first: a thread reads the photos, brightens them and runs COLMAP (which releases the
GIL) while the main thread imports torch and loads the model (1.5-2.5 s of a 2-core restore that
otherwise left a core idle). The job then takes the photos from here instead of reading them again,
and the registration stage reads COLMAP's run instead of starting one
(`pipeline.scene_stages.registration`). The run is the one the job would make itself (the same
pixels, curve and options), so the cameras are the same. A command that fails or is interrupted
meanwhile closes it (`close`): COLMAP stops within its stage and its work folder goes.

This module imports no torch: numpy, OpenCV, OpenImageIO, rawpy and pycolmap only.
"""

from __future__ import annotations

import logging
import tempfile
import threading
from collections.abc import Sequence
from concurrent.futures import Future
from pathlib import Path

import numpy as np
import pycolmap

from lumos3d_cli.checks import require_finite
from lumos3d_cli.eval.tone_curve import auto_gamma_array
from lumos3d_cli.geometry.colmap_run import ColmapRun, ColmapStopped, matching_threads, run_colmap
from lumos3d_cli.io.images import LoadedPhotos, load_photos
from lumos3d_cli.pipeline.presets import RestorePreset

logger = logging.getLogger(__name__)

# How long `close` waits for the thread: a stop lands within COLMAP's stage or after the photo being
# decoded; past this (a photo on a stalled drive) the command ends without it.
CLOSE_WAIT_SECONDS = 10.0


class EarlyRegistration:
    """The photos at `paths` read, then COLMAP run on their blind tone curve at `long_side`, on a
    thread of their own from construction on. `photos()` and `colmap_run()` wait for their part
    and raise what it raised (an unreadable photo: the InputError the job would raise); `close()`
    stops what is left and waits for the thread."""

    def __init__(self, paths: Sequence[Path], long_side: int | None):
        self.paths = list(paths)
        self.long_side = long_side
        self._photos: Future = Future()
        self._run: Future = Future()
        self._stop = pycolmap.CancellationToken()
        self._thread = threading.Thread(target=self._work, name="lumos3d-early-sfm", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop what is left (COLMAP within its stage, the reading after the photo it is on; a
        finished run is kept) and wait for the thread, so that no work folder outlives the
        command (at most CLOSE_WAIT_SECONDS)."""
        self._stop.cancel()
        self._thread.join(CLOSE_WAIT_SECONDS)
        if self._thread.is_alive():
            logger.warning("structure-from-motion did not stop within %.0f s; its work folder may stay in %s",
                           CLOSE_WAIT_SECONDS, tempfile.gettempdir())

    def _check_stop(self, _path: Path) -> None:
        if self._stop.is_cancelled:
            raise ColmapStopped("structure-from-motion was stopped")

    def _work(self) -> None:
        try:
            photos = load_photos(self.paths, progress=self._check_stop)
        except BaseException as error:  # noqa: BLE001 - handed to the thread that waits for it
            self._photos.set_exception(error)
            self._run.set_exception(error)
            return
        self._photos.set_result(photos)
        try:
            brightened = _BrightenedPhotos(photos.pixels)
            self._run.set_result(run_colmap(brightened, photos.original_sizes, self.long_side,
                                            threads=matching_threads(len(self.paths)), stop=self._stop))
        except BaseException as error:  # noqa: BLE001 - handed to the thread that waits for it
            self._run.set_exception(error)

    def photos(self) -> LoadedPhotos:
        """The photos, as `io.images.load_photos` reads them."""
        return self._photos.result()

    def colmap_run(self) -> ColmapRun:
        """COLMAP's run on the photos' blind tone curve (`eval.tone_curve.auto_gamma_array`)."""
        return self._run.result()


class _BrightenedPhotos(Sequence):
    """The photos pixels [V, 3, H, W] through the blind tone curve (`auto_gamma_array`, per
    photo), each computed when structure-from-motion reads it: brightened all at once they were a
    full-resolution copy of every photo, held through the whole registration (3.6 GB for 25
    photos of 12 MP, where SfM sees each at 384 px)."""

    def __init__(self, pixels: np.ndarray):
        self._pixels = pixels

    def __len__(self) -> int:
        return len(self._pixels)

    def __getitem__(self, index: int) -> np.ndarray:
        brightened = auto_gamma_array(self._pixels[index])
        require_finite("photos for structure-from-motion", brightened)
        return brightened


def start_early_registration(paths: Sequence[Path], preset: RestorePreset, geometry: str,
                             poses: Path | str | None) -> EarlyRegistration | None:
    """Structure-from-motion started now when the job would run it on the blind tone curve: the
    preset brightens so for it, the cameras come from structure-from-motion (`geometry` "auto"
    or "sfm", no `poses`) and there are at least two photos. None otherwise (the job refuses a
    `geometry` it does not know)."""
    if preset.sfm_brightening != "tone curve" or geometry not in ("auto", "sfm") or poses is not None or len(paths) < 2:
        return None
    return EarlyRegistration(paths, preset.sfm_long_side)
