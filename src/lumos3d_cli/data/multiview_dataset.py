"""A torch Dataset of multi-view training samples: V overlapping views of one scene, cropped
and resized to the network size, with cameras relative to the first view and sparse depth."""

from __future__ import annotations

import logging
from collections import OrderedDict

import numpy as np
import torch
from torch.utils.data import Dataset

from lumos3d_cli.data.augment import centred_box, crop_and_resize, crop_box, mirror
from lumos3d_cli.data.photo_reading import read_training_photo
from lumos3d_cli.data.scene_records import SceneRecord
from lumos3d_cli.data.view_sampling import candidate_views, sample_views
from lumos3d_cli.io.cameras import invert_rigid, to_homogeneous

logger = logging.getLogger(__name__)

# Decoded views kept per dataset (each data-loading process holds its own): about 700 of LOM's
# 500x375 photos, 250 of DL3DV's 960x540 frames; beyond it the least recently used are decoded again.
IMAGE_CACHE_BYTES = 1 << 30


def project_sparse_depth(points: np.ndarray, extrinsics: torch.Tensor, intrinsics: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """Nearest-pixel z-buffer of world points [P,3] in one view -> [H, W] depth (0 = no point):
    each pixel the nearest point's depth (a min-reduction: an indexed write of repeated pixels
    keeps an unspecified one, which depended on the thread count)."""
    if points.size == 0:
        return torch.zeros(height, width, dtype=torch.float32)
    world = torch.from_numpy(points).to(extrinsics)
    camera = world @ extrinsics[:, :3].T + extrinsics[:, 3]
    z = camera[:, 2]
    front = z > 1e-6
    pixels = (camera[front] / z[front, None]) @ intrinsics.T
    columns = torch.floor(pixels[:, 0]).long()
    rows = torch.floor(pixels[:, 1]).long()
    inside = (columns >= 0) & (columns < width) & (rows >= 0) & (rows < height)
    columns, rows, values = columns[inside], rows[inside], z[front][inside].float()
    depth = torch.full((height * width,), torch.inf)
    depth.scatter_reduce_(0, rows * width + columns, values, reduce="amin")
    return torch.where(torch.isinf(depth), 0.0, depth).view(height, width)


class MultiViewDataset(Dataset):
    """Samples: images [V,3,H,W] (sRGB, normal light), intrinsics [V,3,3], extrinsics [V,3,4]
    (world = first view, translations divided by `scale`), sparse_depth [V,H,W] (same unit;
    0 = none), has_poses, scale (the scene unit: median sparse depth, else mean camera distance).

    Deterministic: sample i of epoch e depends only on (seed, e, i).
    """

    def __init__(
        self,
        records: list[SceneRecord],
        views: int,
        size: tuple[int, int],
        crop_scale: tuple[float, float] = (0.6, 1.0),
        flip: bool = True,
        require_poses: bool = False,
        seed: int = 0,
        samples_per_scene: int = 1,
        cache_bytes: int = IMAGE_CACHE_BYTES,
    ):
        usable = [r for r in records if len(candidate_views(r, require_poses)) >= views]
        dropped = sorted(set(r.name for r in records) - set(r.name for r in usable))
        if dropped:
            logger.warning("%d scene(s) have fewer than %d %sviews and are not used: %s", len(dropped), views,
                           "posed " if require_poses else "", ", ".join(dropped))
        if not usable:
            raise ValueError(f"no scene has {views} {'posed ' if require_poses else ''}views")
        self.records = usable
        self.views = views
        self.width, self.height = size
        self.crop_scale = crop_scale
        self.flip = flip
        self.require_poses = require_poses
        self.seed = seed
        self.samples_per_scene = samples_per_scene
        self.epoch = 0
        self.cache_bytes = cache_bytes
        self._cache: OrderedDict[tuple[int, int], torch.Tensor] = OrderedDict()  # least recently used first
        self._cached_bytes = 0

    def __len__(self) -> int:
        return len(self.records) * self.samples_per_scene

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def _image(self, scene: int, view: int) -> torch.Tensor:
        """View `view` of scene `scene`, [3, H, W] sRGB: decoded once and kept (float16) while the
        cache holds at most `cache_bytes` (a paper-scale data set decodes terabytes over a run)."""
        key = (scene, view)
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key].float()
        pixels = read_training_photo(self.records[scene].image_paths[view])
        image = torch.from_numpy(pixels).permute(2, 0, 1).to(torch.float16)
        self._cache[key] = image
        self._cached_bytes += image.nbytes
        while self._cached_bytes > self.cache_bytes and self._cache:
            self._cached_bytes -= self._cache.popitem(last=False)[1].nbytes
        return image.float()

    def __getitem__(self, index: int) -> dict:
        rng = np.random.default_rng([self.seed, self.epoch, index])
        scene = index % len(self.records)
        record = self.records[scene]
        views = sample_views(record, self.views, rng, self.require_poses)
        images = [self._image(scene, v) for v in views]
        height, width = images[0].shape[-2:]
        rows = [record.camera_of(v) for v in views]
        has_poses = record.cameras is not None and all(r is not None for r in rows)
        intrinsics = extrinsics = None
        points = None
        if has_poses:
            cameras = record.cameras[rows].rescaled_to([(image.shape[-1], image.shape[-2]) for image in images])
            intrinsics = cameras.intrinsics.clone()
            # Re-express in the first view's frame.
            first_to_world = invert_rigid(cameras.extrinsics[0])
            extrinsics = (to_homogeneous(cameras.extrinsics) @ first_to_world)[:, :3, :]
            if record.points_xyz is not None:
                seen = np.unique(np.concatenate([record.observed.get(v, np.empty(0, np.int64)) for v in views]))
                world_to_first = to_homogeneous(cameras.extrinsics[0]).numpy()
                xyz = record.points_xyz[seen]
                points = xyz @ world_to_first[:3, :3].T + world_to_first[:3, 3]
        # views of another size than the first (a portrait photo among landscape ones): their centre at
        # the first view's aspect, resized to its size, never stretched (the intrinsics follow)
        for i, image in enumerate(images):
            if image.shape[-2:] != (height, width):
                box = centred_box(image.shape[-1], image.shape[-2], width, height)
                resized, view = crop_and_resize(image[None], None if intrinsics is None else intrinsics[i : i + 1], box, width, height)
                images[i] = resized[0]
                if intrinsics is not None:
                    intrinsics[i] = view[0]
        images = torch.stack(images)
        scale = rng.uniform(*self.crop_scale)
        box = crop_box(width, height, self.width, self.height, scale, rng)
        images, intrinsics = crop_and_resize(images, intrinsics, box, self.width, self.height)
        if self.flip and rng.random() < 0.5:
            images, intrinsics, extrinsics, points = mirror(images, intrinsics, extrinsics, points)
        sparse = torch.zeros(self.views, self.height, self.width)
        unit = 1.0
        if has_poses:
            if points is not None:
                for i in range(self.views):
                    sparse[i] = project_sparse_depth(points, extrinsics[i], intrinsics[i], self.width, self.height)
            valid = sparse[sparse > 0]
            if valid.numel() >= 10:
                unit = float(valid.median())
            else:
                distances = invert_rigid(extrinsics)[:, :3, 3].norm(dim=1)
                unit = float(distances[1:].mean()) if self.views > 1 and distances[1:].mean() > 0 else 1.0
            extrinsics = extrinsics.clone()
            extrinsics[:, :, 3] /= unit
            sparse /= unit
        return {
            "images": images.float(),
            "intrinsics": (intrinsics if intrinsics is not None else torch.zeros(self.views, 3, 3)).float(),
            "extrinsics": (extrinsics if extrinsics is not None else torch.zeros(self.views, 3, 4)).float(),
            "sparse_depth": sparse,
            "has_poses": torch.tensor(has_poses),
            "scale": torch.tensor(unit, dtype=torch.float32),
            "scene": record.name,
            "views": torch.tensor(views),
        }
