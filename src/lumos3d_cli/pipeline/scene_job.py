"""The state of one scene's build, handed from stage to stage (pipeline/scene_stages.py): what
went in, what each stage made, where the tensors live and how long each stage took."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path

import torch

from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.model.appearance.exposure_prior import prior_strength
from lumos3d_cli.model.lumos3d import GaussianCounts, Lumos3D
from lumos3d_cli.pipeline.early_registration import EarlyRegistration
from lumos3d_cli.pipeline.network_pass import NetworkPass
from lumos3d_cli.pipeline.presets import RestorePreset
from lumos3d_cli.pipeline.progress import JobProgress, SilentProgress
from lumos3d_cli.pipeline.scene_geometry import Brightened, SceneGeometry, ViewRegistration


@dataclass
class SceneJob:
    """One scene on its way from photos to Gaussians.

    What goes in: photos [V, 3, H, W] (the working tensor, sRGB in [0, 1], on the CPU) named
    `names`, each photo's own (width, height) in `sizes` (None: the tensor's), the model, the
    preset, the geometry source, given `poses`, the cap on the views the network sees, the mode,
    the views the network must see (`required_views`) and, for evaluation's holdout, the views
    whose Gaussians are fused (`fuse_views` [V] bool; None: all), and structure-from-motion's run
    on the blind tone curve when it was started before the job (`early_registration`; None: the
    job runs it), and the photos found all black or saturated at their own size (`empty_views`,
    which the exposure prior meters without; None: judged on the working tensor), and for a
    restore, each photo at its own size (`photo_at_own_size`, index -> [3, h, w]; None: not a
    restore, whose views are all renders but a one-photo scene's). `device` is the
    model's: the
    network pass, the Gaussians, the budget and the refinement stay on it.

    What the stages make: `network` (the forward pass over the `selected` views, indices into the
    photos), `brightened` (the photos as structure-from-motion sees them), `registration` (the
    cameras known before the network; `pending_registration` while structure-from-motion runs
    beside the network pass), `geometry` (every view's camera and the aligned depth),
    `grid_size` (the pixel Gaussians' grid per view, width x height), `gaussians` and `counts`,
    `budget` (what `fit_budget` kept, summary.json's gaussians.budget), `refinement` (its summary;
    None: not refined), `restored_photos` [V, 3, H, W] (the operator applied to every photo, CPU;
    set after the network pass; None for a regression model), `photo_restoration` (view index ->
    [3, h, w] at the photo's own size: the photos restored in 2D and denoised where those, not
    renders, are the views, `views_in_2d`; `scene_stages.photo_restoration`) and `denoising` (their
    measured noise and whether it was removed; None: none), `timings` seconds per stage.
    """

    photos: torch.Tensor
    names: list[str]
    model: Lumos3D
    preset: RestorePreset
    geometry_source: str = "auto"
    poses: Path | str | None = None
    max_views: int | None = None
    mode: str = "low-light"
    progress: JobProgress = field(default_factory=SilentProgress)
    required_views: Sequence[int] = ()
    fuse_views: Sequence[bool] | None = None
    sizes: Sequence[tuple[int, int]] | None = None
    early_registration: EarlyRegistration | None = None
    empty_views: Sequence[int] | None = None
    photo_at_own_size: Callable[[int], torch.Tensor] | None = None
    network: NetworkPass | None = None
    selected: list[int] = field(default_factory=list)
    brightened: Brightened | None = None
    registration: ViewRegistration | None = None
    pending_registration: Future | None = None
    geometry: SceneGeometry | None = None
    grid_size: tuple[int, int] | None = None
    gaussians: Gaussians | None = None
    counts: GaussianCounts | None = None
    budget: dict | None = None
    refinement: dict | None = None
    restored_photos: torch.Tensor | None = None
    photo_restoration: dict[int, torch.Tensor] | None = None
    views_in_2d: list[int] = field(default_factory=list)
    denoising: dict | None = None
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def device(self) -> torch.device:
        return next(self.model.parameters()).device

    @property
    def view_limit(self) -> int:
        """The most views the network sees."""
        return self.max_views or self.preset.max_views

    @property
    def network_size(self) -> tuple[int, int]:
        """(width, height) of the network images."""
        return self.network.network_size

    @property
    def has_operator(self) -> bool:
        """Whether the model predicts a restoration operator (else it regresses colours)."""
        return self.model.architecture.appearance == "operator"

    @property
    def exposure(self) -> dict | None:
        """summary.json's exposure_prior: its strength and the gain in stops it gave the scene."""
        if self.network is None or self.network.exposure_stops is None:
            return None
        return {"strength": prior_strength(self.mode, self.preset.exposure_prior), "key": self.preset.exposure_key,
                "stops": round(self.network.exposure_stops, 4)}
