"""Choose V context views of a scene that overlap: views sharing the most sparse points with an
anchor view, or (without points) frames near the anchor in capture order."""

from __future__ import annotations

import numpy as np

from lumos3d_cli.data.scene_records import SceneRecord


def candidate_views(record: SceneRecord, require_poses: bool) -> list[int]:
    return list(record.posed) if require_poses else list(range(len(record.image_paths)))


def sample_views(record: SceneRecord, count: int, rng: np.random.Generator, require_poses: bool) -> list[int]:
    """`count` distinct view indices, the anchor first, the rest in capture order. The pool of
    partners is the 2*count views sharing most points with the anchor (or nearest in order)."""
    candidates = candidate_views(record, require_poses)
    if len(candidates) < count:
        raise ValueError(f"scene {record.name} has {len(candidates)} usable views, fewer than {count}")
    anchor = int(rng.choice(candidates))
    others = [v for v in candidates if v != anchor]
    pool_size = min(len(others), max(2 * count, count - 1))
    anchor_points = record.observed.get(anchor)
    if anchor_points is not None and anchor_points.size and record.observed:
        shared = np.array([np.intersect1d(anchor_points, record.observed.get(v, np.empty(0, np.int64))).size for v in others])
        order = np.lexsort((np.abs(np.array(others) - anchor), -shared))  # most shared, then nearest
    else:
        order = np.argsort(np.abs(np.array(others) - anchor), kind="stable")
    pool = [others[i] for i in order[:pool_size]]
    partners = sorted(int(v) for v in rng.choice(pool, size=count - 1, replace=False)) if count > 1 else []
    return [anchor] + partners
