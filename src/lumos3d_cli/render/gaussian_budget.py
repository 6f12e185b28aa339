"""Fit a fused scene to a Gaussian budget: drop what the views do not show, then cap the count.

Voxel fusion keeps every pixel Gaussian that found no partner, including the many that end up
behind an opaque surface in every view or too faint to pass the alpha threshold anywhere. Their
rendered weight (`render.contribution`) says so: a Gaussian with weight 0 is drawn by no view,
one below `min_weight` pixels (summed over the views) changes the renders by less than that.
A cap then keeps the `max_gaussians` of highest weight.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass

import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.render.contribution import rendered_weights

logger = logging.getLogger(__name__)

# Pixels of rendered weight over all views below which a Gaussian goes: chosen on normal-light
# scenes with benchmarks/gaussian_budget.py (at most 0.04 dB lost there; 1 px lost up to 0.11).
DEFAULT_MIN_WEIGHT = 0.5
# Weights measured at half resolution were not equivalent there (15-20 % more pruned, up to
# 0.08 dB more lost), so the views are rendered at their own size unless asked otherwise.
DEFAULT_RESOLUTION = 1.0


@dataclass(frozen=True)
class BudgetReport:
    """Counts of one `fit_budget`: kept, dropped_unseen (drawn by no view), dropped_weak (weight
    below min_weight), capped (dropped by max_gaussians, the weakest first)."""

    kept: int
    dropped_unseen: int
    dropped_weak: int
    capped: int

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


def select_budget(
    weights: torch.Tensor, min_weight: float = DEFAULT_MIN_WEIGHT, max_gaussians: int | None = None
) -> tuple[torch.Tensor, BudgetReport]:
    """weights [N] -> (keep [N] bool, report): weight > 0 and >= min_weight, then at most
    `max_gaussians` of them, the highest weights (ties: the lower index)."""
    if min_weight < 0:
        raise ValueError(f"min_weight {min_weight} must be >= 0")
    if max_gaussians is not None and max_gaussians < 1:
        raise ValueError(f"max_gaussians {max_gaussians} must be at least 1")
    seen = weights > 0
    keep = seen & (weights >= min_weight)
    capped = 0
    if max_gaussians is not None and int(keep.sum()) > max_gaussians:
        candidates = torch.nonzero(keep).squeeze(1)
        # A stable sort by descending weight keeps the lower index on ties: the cut is deterministic.
        order = torch.argsort(weights[candidates], descending=True, stable=True)
        capped = candidates.shape[0] - max_gaussians
        keep[candidates[order[max_gaussians:]]] = False
    report = BudgetReport(
        kept=int(keep.sum()), dropped_unseen=int((~seen).sum()),
        dropped_weak=int((seen & (weights < min_weight)).sum()), capped=capped,
    )
    return keep, report


def fit_budget(
    gaussians: Gaussians, cameras: Cameras, max_gaussians: int | None = None,
    min_weight: float = DEFAULT_MIN_WEIGHT, resolution: float = DEFAULT_RESOLUTION, grid_pixels: int = 0,
) -> tuple[Gaussians, BudgetReport]:
    """The Gaussians that the `cameras` (the views the scene is rendered at) show: weights from
    `rendered_weights` at `resolution`, selection by `select_budget`. Keeps the input order.
    `grid_pixels`: the pixels of a view's grid of pixel Gaussians; a smaller view's weights count
    in the grid's pixels (else every Gaussian of a photo smaller than the grid weighed under
    `min_weight` and 58 % of a 64x48 view went uncovered)."""
    if len(cameras) == 0:
        raise ValueError("fit_budget needs at least one camera: with none, every Gaussian is unseen")
    weights = rendered_weights(gaussians, cameras, resolution, at_least_pixels=grid_pixels)
    keep, report = select_budget(weights, min_weight, max_gaussians)
    logger.info("Gaussian budget: kept %d of %d (%d drawn by no view, %d below %.3g px of weight, %d over the cap)",
                report.kept, len(gaussians), report.dropped_unseen, report.dropped_weak, min_weight, report.capped)
    return gaussians.select(keep.to(gaussians.means.device)), report
