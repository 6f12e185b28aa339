"""Structure-from-motion's cameras: COLMAP's largest model (`geometry.colmap_run`, where its
choices are measured) read as `Cameras`, sparse points and observations in pixels of each photo at
its own size.

The photos go in already brightened (SIFT finds few features in a dark photo); each is resized
so that its long side is at most `long_side` at its own aspect ratio (a photo stretched into a
common tensor is un-stretched there).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import pycolmap
import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.colmap_run import EXHAUSTIVE_MATCHING_LIMIT, MAX_FEATURES, SFM_LONG_SIDE, ColmapRun, run_colmap
from lumos3d_cli.geometry.similarity import Similarity, transform_cameras
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.colmap import sparse_points_of
from lumos3d_cli.io.images import common_size
from lumos3d_cli.io.sparse_points import SparsePoints

logger = logging.getLogger(__name__)

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

    def without_views(self, views: Sequence[int]) -> Registration:
        """The registration with `views` (indices into the V photos) no longer registered: their
        cameras and their observations go, and so do the points no other view observes (a camera
        with a field of view no lens has is placed like a view that did not register). The frame is
        normalised again as COLMAP normalises its models (`_normalised`): such a camera sits a
        world away, and had squeezed the others into a speck (British Museum's nine into 0.03
        units, nearer than the renderer's near plane)."""
        views = sorted(set(views) & set(self.registered_indices))
        if not views:
            return self
        registered = self.registered.clone()
        registered[views] = False
        rows = [row for row, view in enumerate(self.registered_indices) if view not in views]
        points = self.points
        keep = ~torch.isin(points.view, torch.tensor(views, dtype=torch.int64))
        seen = torch.unique(points.point[keep])
        position = torch.full((len(points),), -1, dtype=torch.int64)
        position[seen] = torch.arange(len(seen))
        points = replace(points, xyz=points.xyz[seen], rgb=points.rgb[seen], error=points.error[seen],
                         view=points.view[keep], point=position[points.point[keep]], pixel=points.pixel[keep])
        cameras, points = _normalised(self.cameras[rows], points)
        # the errors measured again on the observations left (the cameras are indexed by row)
        row_of_view = torch.full((len(registered),), -1, dtype=torch.int64)
        row_of_view[registered] = torch.arange(int(registered.sum()))
        measured, error = replace(points, view=row_of_view[points.view]).reprojected(cameras)
        sizes = [self.model_sizes[0] - len(views), *self.model_sizes[1:]] if self.model_sizes else []
        return replace(self, cameras=cameras, registered=registered, points=replace(measured, view=points.view),
                       reprojection_error=error, model_sizes=sizes)

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
            line += "; the photos overlap too little to join, or show more than one scene"
        return line


# COLMAP's normalisation of a model (Reconstruction::Normalize, run after its global bundle
# adjustments): the 10th to 90th percentiles of the camera centres span a box this wide, centred.
NORMALISED_EXTENT = 10.0
NORMALISED_PERCENTILES = (0.1, 0.9)


def _normalised(cameras: Cameras, points: SparsePoints) -> tuple[Cameras, SparsePoints]:
    """The cameras and points moved and scaled (one similarity) as COLMAP normalises a model; as
    they are without a camera."""
    if len(cameras) == 0:
        return cameras, points
    centres = cameras.centers().double()
    low, high = (torch.quantile(centres, q, dim=0) for q in NORMALISED_PERCENTILES)
    extent = float((high - low).norm())
    scale = NORMALISED_EXTENT / extent if math.isfinite(extent) and extent > 0 else 1.0
    similarity = Similarity(scale, torch.eye(3, dtype=torch.float64), -scale * (low + high) / 2)
    return transform_cameras(cameras, similarity), replace(points, xyz=similarity.apply(points.xyz))


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
    points = replace(at_sfm_size, error=at_sfm_size.error * point_factor,
                     pixel=at_sfm_size.pixel * scale[at_sfm_size.view])
    # the mean over the observations (a point's error is the mean of its track's: weighted by its
    # length), as the docstring and docs say; pycolmap's mean is over the points
    observed = float(points.error[points.point].mean()) if len(points.point) else math.nan
    return cameras, registered, points, observed


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
    run: ColmapRun | None = None,
) -> Registration:
    """Register brightened photos [V, 3, H, W] (sRGB in [0, 1]) named `names` (file names).

    `sizes`: (width, height) of each photo before it was stretched to the tensor's size (None:
    the tensor's size); SfM sees each photo at its own aspect ratio and returns its camera at its
    own size. Returns the largest model SfM found; a Registration with `failed` set (not an
    exception) when fewer than two views register (blank, textureless or unrelated photos), so
    that a caller can fall back to other cameras. `shared_camera`: the photos come from one camera
    with one focal length (photos of different sizes then share one camera per size; False: one
    camera per photo). `threads`: CPU threads of matching and mapping (None: all cores; 1: a
    repeatable result); the features are extracted on every core. `run`: COLMAP's run on these
    photos already made (`geometry.colmap_run.run_colmap` with the same arguments, started before
    torch was imported: `pipeline.early_registration`), read instead of running again.
    InputError for fewer than 2 photos, a name or size count that does not match, or non-finite
    pixels.
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
    if run is None:
        require_finite("photos for structure-from-motion", images)
        run = run_colmap(images.float().numpy(), photo_sizes, long_side, exhaustive_limit, shared_camera, threads,
                         max_features)
    elif len(run.sfm_sizes) != views or run.long_side != long_side:
        raise ValueError(f"a COLMAP run of {len(run.sfm_sizes)} photos at {run.long_side} px given for {views} at "
                         f"{long_side} px")
    sfm_sizes, matching = run.sfm_sizes, run.matching
    model_sizes = _model_sizes(run.models)
    if model_sizes:
        largest = max(run.models, key=lambda model: model.num_reg_images())
        cameras, registered, points, error = _read_model(largest, names, photo_sizes, sfm_sizes)
    else:
        empty = torch.zeros(0, 3, 4, dtype=torch.float64)
        cameras = Cameras(empty, torch.zeros(0, 3, 3, dtype=torch.float64), [], [])
        registered, points, error = torch.zeros(views, dtype=torch.bool), SparsePoints.empty(), float("nan")
    registration = Registration(cameras, registered, points, error, model_sizes, matching, sfm_sizes,
                                run.seconds, run.stage_seconds)
    if len(cameras):
        cameras.require_valid("structure-from-motion cameras", remedy="use the network's cameras, or give poses")
    others = len(set(sfm_sizes)) - 1
    logger.info("structure-from-motion: %s in %.1f s (%s matching at %dx%d%s; %d points, %.2f px)",
                registration.describe(), registration.seconds, matching, *registration.sfm_size,
                f" and {others} other size(s)" if others else "", len(points), error)
    return registration
