"""Structure-from-motion's COLMAP run with pycolmap: SIFT features, matching, incremental mapping,
on the CPU, from numpy pixels to COLMAP's models (`geometry.sfm` reads them as cameras). It needs
no torch: a restore starts it before torch is imported (`pipeline.early_registration`).

The photos go in already brightened (SIFT finds few features in a dark photo); each is resized
so that its long side is at most `long_side` at its own aspect ratio (a photo stretched into a
common tensor is un-stretched here), written as an uncompressed BMP into a temporary folder (0.02 s
for 25 photos of 500x375, where PNG took 0.43 s: the pixels are the same), and registered
there. Cameras, sparse points and observations come back in pixels of each photo at its own size.

Choices, measured on LOM buu (500x375) and the Strecha scenes (768x512) on 2 CPU cores
(benchmarks/sfm.py; docs/performance.md, "Structure-from-motion"; the seconds there were taken
with the cores shared by other jobs):
- long side 512 px: on fountain-P11 the same rotation accuracy as full resolution (0.36 vs 0.33
  degrees median) in half the time (9.0 vs 19.0 s shared; 2.5 vs 5.2 s alone);
- all CPU cores: on an idle machine 2 threads took 4.0 s on buu's 25 views, 1 thread 6.7 s;
  the features are always extracted on every core (`extraction_threads`): the photos enter the
  database first, in input order, so each keeps its image id whichever thread finishes first
  (COLMAP's extractor numbers new images in the order they finish, and the mapper's result
  depends on the numbering: two threaded runs gave focal lengths 735.1 and 736.4 px on buu);
- exhaustive matching up to EXHAUSTIVE_MATCHING_LIMIT (25) views: there it costs about what
  sequential matching does (buu, 25 views: 4.2 vs 3.0 s) and does not depend on the photos'
  order; above it the quadratic cost shows (castle-P30: 20.5 vs 6.1 s; 48 views: 19.9 vs 5.3 s),
  so each view is matched with its next SEQUENTIAL_OVERLAP views in the given order (plus
  quadratic strides), which needs no vocabulary tree and registered 48/48 and 29/30 views with
  the same accuracy;
- MAX_FEATURES SIFT features per photo (COLMAP's default is 8192): brute-force matching cost
  grows with its square, and every scene above registers all its views with 4096 (exhaustive);
- geometric verification's RANSAC floor at VERIFICATION_MIN_TRIALS (20; COLMAP's 100): the
  trials a pair needs follow its inlier ratio, and the floor binds only where nearly all matches
  are inliers, which was most of buu's 300 pairs: matching 1.81 -> 1.06 s at 384 px, the same
  rotation accuracy within run-to-run noise on Strecha and buu (mean of the median errors over
  Herz-Jesus-P8, fountain-P11, entry-P10, castle-P19 and buu: 0.82 -> 0.60 degrees at 384 px,
  0.41 -> 0.42 at 512) and every view registered. Only from VERIFICATION_FLOOR_FROM_VIEWS (20)
  photos up: under it the pairs are few and the floor saved no time (Strecha's 8-19 photos:
  within 0.1 s), and 9 of buu's photos in three sizes (one camera each) put the 400x300 photo's
  focal length 10 % off the expected 0.8x with it, 3 % with COLMAP's 100;
- one shared SIMPLE_PINHOLE camera (one focal length, principal point at the image centre, no
  distortion) when the photos come from one camera: the renderer is a pinhole, and one focal
  length is better constrained than two. It lands within 0.5 % of fountain's calibrated focal.
  Photos of different sizes get one such camera per size: a focal length in pixels and a
  principal point at the image centre hold for one size only.

COLMAP runs multi-threaded and is then not bit-reproducible; with few photos (about 6) its focal
length can settle in a wrong minimum on some runs. `threads=1` (matching and mapping: their
RANSAC draws depend on which thread takes which pair) makes a run deterministic.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pycolmap

from lumos3d_cli.io.work_folders import work_folder

SFM_LONG_SIDE = 512
EXHAUSTIVE_MATCHING_LIMIT = 25
SEQUENTIAL_OVERLAP = 10
# SIFT features per photo: brute-force matching costs grows with the square of this.
MAX_FEATURES = 4096
# The fewest RANSAC trials of a pair's geometric verification, from this many photos up; fewer
# photos keep COLMAP's 100 (module docstring).
VERIFICATION_MIN_TRIALS = 20
VERIFICATION_FLOOR_FROM_VIEWS = 20


class ColmapStopped(Exception):
    """A COLMAP run was asked to stop (its `stop` token cancelled) and did."""


@dataclass
class ColmapRun:
    """What COLMAP made of V photos: its models (each a pycolmap.Reconstruction, whose image
    names are the photos' input indices, `image_files`), the matching used ("exhaustive" or
    "sequential"), the (width, height) it saw each photo at, the longest side asked for (None:
    the photos' own size), and seconds: the whole run, stage_seconds: features, matching, mapping."""

    models: list[pycolmap.Reconstruction]
    matching: str
    sfm_sizes: list[tuple[int, int]]
    long_side: int | None
    seconds: float
    stage_seconds: dict[str, float]


def sfm_size(width: int, height: int, long_side: int | None) -> tuple[int, int]:
    """(width, height) SfM runs at: the photo shrunk to `long_side` (never enlarged; None: as is)."""
    if long_side is None or max(width, height) <= long_side:
        return width, height
    factor = long_side / max(width, height)
    return max(1, round(width * factor)), max(1, round(height * factor))


def sfm_pixels(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """[3, H, W] float sRGB in [0, 1] -> [height, width, 3] uint8 BGR for OpenCV."""
    pixels = (np.clip(image.transpose(1, 2, 0).astype(np.float32, copy=False), 0, 1) * 255.0 + 0.5).astype(np.uint8)
    if (pixels.shape[1], pixels.shape[0]) != (width, height):
        pixels = cv2.resize(pixels, (width, height), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(pixels[..., ::-1])


def matching_threads(views: int) -> int | None:
    """The threads of matching and mapping for `views` photos: one makes COLMAP's result repeatable
    (with more, a small photo set can settle on another focal length from run to run); above the
    exhaustive-matching range speed matters more (None: all cores)."""
    return 1 if views <= EXHAUSTIVE_MATCHING_LIMIT else None


def _options(threads: int, max_features: int, views: int, extraction_threads: int):
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "SIMPLE_PINHOLE"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = extraction_threads
    extraction.sift.max_num_features = max_features
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    verification = pycolmap.TwoViewGeometryOptions()
    if views >= VERIFICATION_FLOOR_FROM_VIEWS:
        verification.ransac.min_num_trials = VERIFICATION_MIN_TRIALS
    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.num_threads = threads
    mapping.random_seed = 0
    # COLMAP drops models under 10 views by default; keep small ones to see how photos split.
    mapping.min_model_size = 2 if views < 10 else 3
    if views == 2:
        # Two photos have only two-view tracks, which COLMAP ignores by default, and close
        # viewpoints: with these settings 4 of 4 buu pairs registered (0.5-1.2 degrees), else none.
        mapping.triangulation.ignore_two_view_tracks = False
        mapping.mapper.init_min_tri_angle = 4.0
    return reader, extraction, matching, verification, mapping


def image_files(photo_sizes: Sequence[tuple[int, int]], shared_camera: bool
                ) -> tuple[list[str], pycolmap.CameraMode]:
    """Each photo's file in SfM's folder (named by input index) and how COLMAP assigns cameras:
    one for all photos of one camera; one per photo size when the sizes differ, a sub-folder
    each (COLMAP's single camera refuses other image sizes); else one per photo."""
    files = [f"{index:05d}.bmp" for index in range(len(photo_sizes))]
    if not shared_camera:
        return files, pycolmap.CameraMode.PER_IMAGE
    if len(set(photo_sizes)) == 1:
        return files, pycolmap.CameraMode.SINGLE
    folders = [f"{width}x{height}/{file}" for (width, height), file in zip(photo_sizes, files)]
    return folders, pycolmap.CameraMode.PER_FOLDER


_quiet_lock = threading.Lock()
_quiet_runs = 0
_level_before_quiet = 0


@contextmanager
def quiet_colmap() -> Iterator[None]:
    """COLMAP's logging off (its progress and failures: the caller logs what they mean) while at
    least one run is inside, then as it was: the level is the process's, and two runs in two
    threads, each putting back what it found, left it off for good."""
    global _quiet_runs, _level_before_quiet
    with _quiet_lock:
        if _quiet_runs == 0:
            _level_before_quiet = pycolmap.logging.minloglevel
            pycolmap.logging.minloglevel = 3
        _quiet_runs += 1
    try:
        yield
    finally:
        with _quiet_lock:
            _quiet_runs -= 1
            if _quiet_runs == 0:
                pycolmap.logging.minloglevel = _level_before_quiet


def run_colmap(
    images: Sequence[np.ndarray],
    photo_sizes: Sequence[tuple[int, int]],
    long_side: int | None = SFM_LONG_SIDE,
    exhaustive_limit: int = EXHAUSTIVE_MATCHING_LIMIT,
    shared_camera: bool = True,
    threads: int | None = None,
    max_features: int = MAX_FEATURES,
    stop: pycolmap.CancellationToken | None = None,
) -> ColmapRun:
    """COLMAP on V brightened photos, each [3, H, W] float sRGB in [0, 1] (possibly stretched to a
    common size), whose own (width, height) are `photo_sizes`: each is seen at its own aspect
    ratio, its long side at most `long_side`. `shared_camera`, `threads`, `max_features`:
    `geometry.sfm.register_photos`. COLMAP's log is silenced; what it found is the caller's to
    report. `stop` cancelled: ColmapStopped within the stage it is in (COLMAP checks the token as
    it goes: 0.1-0.6 s on buu's 25 photos), the work folder removed."""
    token = stop if stop is not None else pycolmap.CancellationToken()

    def check_stop() -> None:
        if token.is_cancelled:
            raise ColmapStopped("structure-from-motion was stopped")

    views = len(images)
    sfm_sizes = [sfm_size(w, h, long_side) for w, h in photo_sizes]
    cores = os.cpu_count() or 1
    reader, extraction, matching_options, verification, mapping = _options(threads or cores, max_features, views, cores)
    files, mode = image_files(photo_sizes, shared_camera)
    matching = "exhaustive" if views <= exhaustive_limit else "sequential"
    stage_seconds = {}
    started = time.perf_counter()
    try:
        with quiet_colmap(), work_folder("lumos3d-sfm-") as work:
            folder, database = work / "images", work / "database.db"
            folder.mkdir()
            for index, file in enumerate(files):
                check_stop()
                (folder / file).parent.mkdir(exist_ok=True)
                cv2.imwrite(str(folder / file), sfm_pixels(images[index], *sfm_sizes[index]))
            pycolmap.set_random_seed(0)
            # The images enter the database in input order first: the extractor then fills in
            # their features under those ids, however its threads finish (module docstring).
            pycolmap.Database.open(str(database)).close()
            pycolmap.import_images(database, folder, mode, files, reader)
            pycolmap.extract_features(database, folder, files, camera_mode=mode, reader_options=reader,
                                      extraction_options=extraction, device=pycolmap.Device.cpu,
                                      cancellation_token=token)
            stage_seconds["features"] = time.perf_counter() - started
            check_stop()
            if matching == "exhaustive":
                pycolmap.match_exhaustive(database, matching_options=matching_options, verification_options=verification,
                                          device=pycolmap.Device.cpu, cancellation_token=token)
            else:
                pairing = pycolmap.SequentialPairingOptions()
                pairing.overlap = SEQUENTIAL_OVERLAP
                pycolmap.match_sequential(database, matching_options=matching_options, pairing_options=pairing,
                                          verification_options=verification, device=pycolmap.Device.cpu,
                                          cancellation_token=token)
            stage_seconds["matching"] = time.perf_counter() - started - stage_seconds["features"]
            check_stop()
            (work / "models").mkdir()
            models = pycolmap.incremental_mapping(database, folder, work / "models", mapping,
                                                  cancellation_token=token)
            stage_seconds["mapping"] = time.perf_counter() - started - stage_seconds["features"] - stage_seconds["matching"]
    except InterruptedError as error:  # pycolmap's answer to a cancelled token
        if not token.is_cancelled:
            raise
        raise ColmapStopped("structure-from-motion was stopped") from error
    return ColmapRun(list(models.values()), matching, sfm_sizes, long_side, time.perf_counter() - started, stage_seconds)
