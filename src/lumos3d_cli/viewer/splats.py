"""Gaussians -> the arrays viser's splat renderer takes, subsampled to what a browser handles."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import torch

from lumos3d_cli.io.gaussians import Gaussians, sh_dc_to_rgb
from lumos3d_cli.rotations import quaternion_to_matrix
from lumos3d_cli.viewer.defaults import DEFAULT_MAX_SPLATS

logger = logging.getLogger(__name__)


@dataclass
class SplatArrays:
    """What `SceneApi.add_gaussian_splats` takes, in viewer coordinates.

    centers [N, 3] float32; covariances [N, 3, 3] float32 (viser stores the upper triangle as
    float16); rgbs [N, 3] float32 in [0, 1]; opacities [N, 1] float32 in [0, 1];
    total: Gaussians in the scene before subsampling.
    """

    centers: np.ndarray
    covariances: np.ndarray
    rgbs: np.ndarray
    opacities: np.ndarray
    total: int

    def __len__(self) -> int:
        return self.centers.shape[0]


def splat_importance(gaussians: Gaussians) -> torch.Tensor:
    """[N] float64 how much each Gaussian can cover on screen, in log: opacity x the area of its
    two largest axes (-inf for a transparent or flat one).

    Keeping the largest values first drops faint and tiny splats, which change the picture the
    least (the significance score of LightGaussian-style pruning, without rendering). In log, as a
    product in float32 made a transparent huge Gaussian 0 x inf = NaN, which topk ranks first."""
    largest_two = gaussians.scales.double().sort(dim=-1).values[:, 1:]
    # transparent and infinite (-inf + inf, a caller's tensor: read_ply refuses infinite scales) ranks last
    return torch.nan_to_num(gaussians.opacities.double().log() + largest_two.log().sum(dim=-1), nan=-math.inf)


def select_splats(gaussians: Gaussians, max_splats: int) -> Gaussians:
    """At most `max_splats` Gaussians, the most important ones (all of them when they fit)."""
    if max_splats < 1:
        raise ValueError(f"max_splats {max_splats}: keep at least one splat")
    if len(gaussians) <= max_splats:
        return gaussians
    return gaussians.select(torch.topk(splat_importance(gaussians), max_splats).indices)


def covariances(quats: torch.Tensor, scales: torch.Tensor) -> torch.Tensor:
    """quats [N, 4] wxyz, scales [N, 3] (standard deviations) -> [N, 3, 3] R diag(s^2) R^T."""
    rotations = quaternion_to_matrix(quats)
    return rotations @ torch.diag_embed(scales.square()) @ rotations.transpose(-1, -2)


# viser sends covariances as float16 (largest 65504): a splat's standard deviation in the viewer's
# frame (the scene's cameras about a unit apart) is capped below its square root, so that a huge
# Gaussian reaches the browser as a very large splat, not as infinity.
MAX_SPLAT_SCALE = 255.0
# The farthest centre sent (in viewer units, the scene's radius about 1): well inside float32, and
# far past anything a camera of the scene can show.
_FARTHEST = 1e30


def splat_arrays(gaussians: Gaussians, centre: torch.Tensor, scale: float, max_splats: int = DEFAULT_MAX_SPLATS) -> SplatArrays:
    """Subsample (see `select_splats`) and move into the viewer frame x' = (x - centre) * scale.

    viser draws one colour per splat, so view-dependent colour (SH degree > 0) is dropped and the
    degree-0 colour 0.5 + C0 * f_dc is shown."""
    shown = select_splats(gaussians, max_splats).map(lambda t: t.detach().to("cpu", torch.float64))
    centers = (shown.means - centre.to(shown.means)) * scale
    beyond = ~(centers.abs() <= _FARTHEST).all(dim=1)
    if bool(beyond.any()):  # float32 would send them as Inf, which the browser cannot place
        logger.warning("%d Gaussian(s) lie too far from the scene for the viewer (beyond %g times its radius); not "
                       "shown", int(beyond.sum()), _FARTHEST)
        shown, centers = shown.select(torch.nonzero(~beyond).flatten()), centers[~beyond]
    sigma = covariances(shown.quats, (shown.scales * scale).clamp(max=MAX_SPLAT_SCALE))
    rgbs = sh_dc_to_rgb(shown.sh[:, 0, :]).clamp(0.0, 1.0)
    return SplatArrays(
        centers.float().numpy(), sigma.float().numpy(), rgbs.float().numpy(),
        shown.opacities.clamp(0.0, 1.0)[:, None].float().numpy(), len(gaussians),
    )
