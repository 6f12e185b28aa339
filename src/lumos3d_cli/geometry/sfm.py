"""Structure-from-motion with pycolmap: SIFT features, matching, incremental mapping, on the CPU.

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

import logging
import os
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
import pycolmap
import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.errors import InputError
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.colmap import sparse_points_of
from lumos3d_cli.io.images import common_size
from lumos3d_cli.io.sparse_points import SparsePoints

logger = logging.getLogger(__name__)

SFM_LONG_SIDE = 512
EXHAUSTIVE_MATCHING_LIMIT = 25
SEQUENTIAL_OVERLAP = 10
# SIFT features per photo: brute-force matching costs grows with the square of this.
MAX_FEATURES = 4096
# The fewest RANSAC trials of a pair's geometric verification, from this many photos up; fewer
# photos keep COLMAP's 100 (module docstring).
VERIFICATION_MIN_TRIALS = 20
VERIFICATION_FLOOR_FROM_VIEWS = 20
# Below this share of photos in the largest model, photos do not look like one scene.
ONE_SCENE_SHARE = 0.5


@dataclass
class Registration:
    """What structure-from-motion recovered from V photos (its largest model).

    cameras: the registered views only, in input order, at the photos' resolution (world->camera,
    OpenCV axes, as every `Cameras`); registered: bool [V]; points: the model's sparse points
    (observations index the V photos); reprojection_error: mean over observations, in pixels of
    the photos (nan when nothing registered); model_sizes: views of the largest model, then the
    views each disconnected further model adds (empty when none was found); matching:
    "exhaustive" or "sequential"; sfm_sizes: (width, height) SfM ran each photo at; seconds: the
    whole run, stage_seconds: features, matching, mapping.
    """

    cameras: Cameras
    registered: torch.Tensor
    points: SparsePoints
    reprojection_error: float
    model_sizes: list[int]
    matching: str
    sfm_sizes: list[tuple[int, int]]
    seconds: float
    stage_seconds: dict[str, float] = field(default_factory=dict)

    @property
    def sfm_size(self) -> tuple[int, int]:
        """The (width, height) SfM ran most photos at."""
        return common_size(self.sfm_sizes)

    @property
    def registered_count(self) -> int:
        return int(self.registered.sum())

    @property
    def registered_indices(self) -> list[int]:
        """Indices into the V photos of `cameras`' rows."""
        return torch.nonzero(self.registered).flatten().tolist()

    @property
    def failed(self) -> bool:
        """Fewer than two views registered: there are no usable cameras."""
        return self.registered_count < 2

    @property
    def looks_like_one_scene(self) -> bool:
        """False when SfM found several disconnected models or its largest holds under half the
        photos: the photos probably do not show one scene (or overlap too little)."""
        return len(self.model_sizes) <= 1 and self.registered_count >= ONE_SCENE_SHARE * len(self.registered)

    def describe(self) -> str:
        """One line for logs and warnings, e.g. 'registered 9 of 25 photos; 3 models (9, 4, 2 views)'."""
        line = f"registered {self.registered_count} of {len(self.registered)} photos"
        if not self.model_sizes:
            return line + " (no model: too few features or matches; blank, dark or unrelated photos?)"
        if len(self.model_sizes) > 1:
            line += f"; {len(self.model_sizes)} disconnected models ({', '.join(map(str, self.model_sizes))} views)"
        if not self.looks_like_one_scene:
            line += "; the photos do not look like one scene"
        return line


def _to_uint8(image: torch.Tensor, width: int, height: int) -> np.ndarray:
    """[3, H, W] float sRGB in [0, 1] -> [height, width, 3] uint8 BGR for OpenCV."""
    pixels = (image.permute(1, 2, 0).float().clamp(0, 1).numpy() * 255.0 + 0.5).astype(np.uint8)
    if (pixels.shape[1], pixels.shape[0]) != (width, height):
        pixels = cv2.resize(pixels, (width, height), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(pixels[..., ::-1])


def sfm_size(width: int, height: int, long_side: int | None) -> tuple[int, int]:
    """(width, height) SfM runs at: the photo shrunk to `long_side` (never enlarged; None: as is)."""
    if long_side is None or max(width, height) <= long_side:
        return width, height
    factor = long_side / max(width, height)
    return max(1, round(width * factor)), max(1, round(height * factor))


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


def _image_files(photo_sizes: Sequence[tuple[int, int]], shared_camera: bool
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


def _group_means(values: torch.Tensor, groups: torch.Tensor, count: int) -> torch.Tensor:
    """[count] means of values [N] by group index [N]; a group whose values are all equal gets
    that value exactly (photos of one size keep COLMAP's figures scaled exactly as one factor)."""
    low = values.new_full((count,), float("inf")).scatter_reduce(0, groups, values, "amin")
    high = values.new_full((count,), float("-inf")).scatter_reduce(0, groups, values, "amax")
    mean = values.new_zeros(count).index_add(0, groups, values) / torch.bincount(groups, minlength=count).clamp(min=1)
    return torch.where(low == high, low, mean)


def _read_model(
    model: pycolmap.Reconstruction, names: Sequence[str], photo_sizes: Sequence[tuple[int, int]],
    sfm_sizes: Sequence[tuple[int, int]],
) -> tuple[Cameras, torch.Tensor, SparsePoints, float]:
    """The model's cameras, registered mask [V], points and mean error, in pixels of each photo at
    its own size."""
    views = len(names)
    # [V, 2] photo pixels per SfM pixel, along x and y
    scale = torch.tensor([[width / sfm_width, height / sfm_height] for (width, height), (sfm_width, sfm_height)
                          in zip(photo_sizes, sfm_sizes)], dtype=torch.float64)
    registered = torch.zeros(views, dtype=torch.bool)
    extrinsics, intrinsics = {}, {}
    view_of_image = {}
    for image_id, image in model.images.items():
        if not image.has_pose:
            continue
        index = int(Path(image.name).stem)  # files are named by input index
        view_of_image[image_id] = index
        registered[index] = True
        extrinsics[index] = torch.from_numpy(image.cam_from_world().matrix()).double()
        calibration = torch.from_numpy(model.cameras[image.camera_id].calibration_matrix()).double()
        calibration[:2] *= scale[index][:, None]
        intrinsics[index] = calibration
    order = sorted(extrinsics)
    cameras = Cameras(
        torch.stack([extrinsics[i] for i in order]) if order else torch.zeros(0, 3, 4, dtype=torch.float64),
        torch.stack([intrinsics[i] for i in order]) if order else torch.zeros(0, 3, 3, dtype=torch.float64),
        [photo_sizes[i] for i in order], [names[i] for i in order],
    )
    # The model's pixels are SfM's (resized) pixels: back to the photos'. An error (a length)
    # scales by the mean of the x and y factors of the views that measured it.
    at_sfm_size = sparse_points_of(model, view_of_image)
    factor = scale.mean(dim=1)[at_sfm_size.view]  # [O]
    point_factor = _group_means(factor, at_sfm_size.point, len(at_sfm_size))
    mean_factor = float(_group_means(factor, torch.zeros_like(at_sfm_size.view), 1)[0])
    points = replace(at_sfm_size, error=at_sfm_size.error * point_factor,
                     pixel=at_sfm_size.pixel * scale[at_sfm_size.view])
    return cameras, registered, points, model.compute_mean_reprojection_error() * mean_factor


def _registered_names(model: pycolmap.Reconstruction) -> set[str]:
    return {image.name for image in model.images.values() if image.has_pose}


def _model_sizes(models: list[pycolmap.Reconstruction]) -> list[int]:
    """Registered views of the largest model, then of each further model the views it adds
    (COLMAP's further models may re-register views of the first: those do not split the scene);
    models that add fewer than 2 views are left out."""
    models = sorted(models, key=lambda model: model.num_reg_images(), reverse=True)
    if not models or models[0].num_reg_images() == 0:
        return []
    largest = _registered_names(models[0])
    others = [len(_registered_names(model) - largest) for model in models[1:]]
    return [len(largest)] + sorted((count for count in others if count >= 2), reverse=True)


def register_photos(
    images: torch.Tensor,
    names: Sequence[str],
    long_side: int | None = SFM_LONG_SIDE,
    exhaustive_limit: int = EXHAUSTIVE_MATCHING_LIMIT,
    shared_camera: bool = True,
    threads: int | None = None,
    max_features: int = MAX_FEATURES,
    sizes: Sequence[tuple[int, int]] | None = None,
) -> Registration:
    """Register brightened photos [V, 3, H, W] (sRGB in [0, 1]) named `names` (file names).

    `sizes`: (width, height) of each photo before it was stretched to the tensor's size (None:
    the tensor's size); SfM sees each photo at its own aspect ratio and returns its camera at its
    own size. Returns the largest model SfM found; a Registration with `failed` set (not an
    exception) when fewer than two views register (blank, textureless or unrelated photos), so
    that a caller can fall back to other cameras. `shared_camera`: the photos come from one camera
    with one focal length (photos of different sizes then share one camera per size; False: one
    camera per photo). `threads`: CPU threads of matching and mapping (None: all cores; 1: a
    repeatable result); the features are extracted on every core. InputError for fewer than 2
    photos, a name or size count that does not match, or non-finite pixels.
    """
    if images.dim() != 4 or images.shape[1] != 3:
        raise InputError(f"structure-from-motion needs images [V, 3, H, W], got {tuple(images.shape)}")
    views, _, height, width = images.shape
    if views < 2:
        raise InputError(f"structure-from-motion needs at least 2 photos of the scene, got {views}")
    if len(names) != views:
        raise InputError(f"{len(names)} names for {views} photos")
    photo_sizes = [(int(w), int(h)) for w, h in sizes] if sizes is not None else [(width, height)] * views
    if len(photo_sizes) != views:
        raise InputError(f"{len(photo_sizes)} photo sizes for {views} photos")
    require_finite("photos for structure-from-motion", images)
    sfm_sizes = [sfm_size(w, h, long_side) for w, h in photo_sizes]
    cores = os.cpu_count() or 1
    reader, extraction, matching_options, verification, mapping = _options(threads or cores, max_features, views, cores)
    files, mode = _image_files(photo_sizes, shared_camera)
    matching = "exhaustive" if views <= exhaustive_limit else "sequential"
    stage_seconds = {}
    started = time.perf_counter()
    previous_level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 3  # COLMAP's progress and failures: we log what they mean
    try:
        with tempfile.TemporaryDirectory(prefix="lumos3d-sfm-") as work:
            folder, database = Path(work) / "images", Path(work) / "database.db"
            folder.mkdir()
            for index, file in enumerate(files):
                (folder / file).parent.mkdir(exist_ok=True)
                cv2.imwrite(str(folder / file), _to_uint8(images[index], *sfm_sizes[index]))
            pycolmap.set_random_seed(0)
            # The images enter the database in input order first: the extractor then fills in
            # their features under those ids, however its threads finish (module docstring).
            pycolmap.Database.open(str(database)).close()
            pycolmap.import_images(database, folder, mode, files, reader)
            pycolmap.extract_features(database, folder, files, camera_mode=mode, reader_options=reader,
                                      extraction_options=extraction, device=pycolmap.Device.cpu)
            stage_seconds["features"] = time.perf_counter() - started
            if matching == "exhaustive":
                pycolmap.match_exhaustive(database, matching_options=matching_options, verification_options=verification,
                                          device=pycolmap.Device.cpu)
            else:
                pairing = pycolmap.SequentialPairingOptions()
                pairing.overlap = SEQUENTIAL_OVERLAP
                pycolmap.match_sequential(database, matching_options=matching_options, pairing_options=pairing,
                                          verification_options=verification, device=pycolmap.Device.cpu)
            stage_seconds["matching"] = time.perf_counter() - started - stage_seconds["features"]
            (Path(work) / "models").mkdir()
            models = pycolmap.incremental_mapping(database, folder, Path(work) / "models", mapping)
            stage_seconds["mapping"] = time.perf_counter() - started - stage_seconds["features"] - stage_seconds["matching"]
            model_sizes = _model_sizes(list(models.values()))
            if model_sizes:
                largest = max(models.values(), key=lambda model: model.num_reg_images())
                cameras, registered, points, error = _read_model(largest, names, photo_sizes, sfm_sizes)
            else:
                empty = torch.zeros(0, 3, 4, dtype=torch.float64)
                cameras = Cameras(empty, torch.zeros(0, 3, 3, dtype=torch.float64), [], [])
                registered, points, error = torch.zeros(views, dtype=torch.bool), SparsePoints.empty(), float("nan")
    finally:
        pycolmap.logging.minloglevel = previous_level
    registration = Registration(cameras, registered, points, error, model_sizes, matching, sfm_sizes,
                                time.perf_counter() - started, stage_seconds)
    if len(cameras):
        cameras.require_valid("structure-from-motion cameras")
    others = len(set(sfm_sizes)) - 1
    logger.info("structure-from-motion: %s in %.1f s (%s matching at %dx%d%s; %d points, %.2f px)",
                registration.describe(), registration.seconds, matching, *registration.sfm_size,
                f" and {others} other size(s)" if others else "", len(points), error)
    return registration
