"""Speed/accuracy presets of `lumos3d restore` and `lumos3d eval`: how many views the network
sees, at which resolution (relative to the model's), the SH degree written and rendered, the
voxel size (relative to the model's pixel footprint), the steps of test-time refinement
(pipeline.scene_refinement) and whether it densifies (refine.densification), the most Gaussians a scene may keep (render.gaussian_budget), and
two speed settings: the size structure-from-motion sees the photos at (geometry.colmap_run) and the
resolution the budget renders the Gaussians' weights at; the size of the images refinement
fits (`balanced` and `best` fit LOM's 500x375 photos at their own size, `fast` at most
256 px); the decay of refinement's learning rates, the strength of the exposure prior
(model.appearance.exposure_prior, one per mode), whether the rendered views' uncovered pixels are
filled (render.hole_filling) and whether a one-photo restore's amplified noise is removed
(model.appearance.amplified_noise), all four the same in every preset."""

from __future__ import annotations

import numbers
from dataclasses import dataclass, replace

from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.colmap_run import SFM_LONG_SIDE
from lumos3d_cli.geometry.sweep_settings import DepthSweepSettings
from lumos3d_cli.pipeline.choices import EXPOSURE_KEYS
from lumos3d_cli.refine.settings import DensifySettings, RefineSettings


# Refinement's learning rates fall by a tenth over 200 steps in every preset: at constant rates the
# steps after 25 fit the noise the operator amplifies in the darkest photos (on buu's holdout frames
# 200 steps scored 23.68 dB / 0.888 at constant rates and 23.76 / 0.891 decaying; on Strecha's
# fountain-P11 darkened to exposure 0.1-0.2 with noise, a scene that is not LOM, 18.04 dB at 25
# steps and 18.57 at 200 decaying). A hundredth over 200 steps lost 0.2 dB on fountain-P11; 25
# decaying steps scored as 25 constant ones on buu (23.65 / 0.889).
REFINE_LR_DECAY = 0.1 ** 0.5  # per 100 steps

# Densification during refinement (refine.densification): 5 % of the Gaussians, those with the
# largest image-space gradients, split or cloned every 10 steps up to step 80 (at most about 1.5x
# the Gaussians, within --max-gaussians); `best` densifies, `--densify` turns it on in the others.
# On the development scenes (buu and shrub, both modes, holdout, the mean of the four), 200 steps:
# up to step 80 20.16 dB / 0.692 / sharpness 0.86, up to step 150 20.15 / 0.693 / 0.89 with 1.4x
# the Gaussians and more specks of the colour chart's black border around it in buu's low-light
# novel views (23.51 dB there against 23.70), so 80. At 25 steps (`balanced`'s then), densifying every 8
# steps lost 0.17 dB and 0.008 SSIM for sharpness 0.77 -> 0.79: the new Gaussians need steps to settle.
# 10 % every 10 steps instead of 5 % (`best`, the sweep over +-25 % with its check; one evaluation):
# 21.23 / 0.741 / 22.31 / 0.93 against 21.18 / 0.742 / 22.33 / 0.92, all of it shrub's (over-exposed
# 18.09 -> 18.31 dB, low light 17.60 -> 17.65) while buu lost 0.05 dB in both modes, in about 15 %
# more time: a gain on one scene's foliage that the indoor scenes pay for, so 5 %.
DENSIFY = DensifySettings()

# Every preset refines the registered depth by a plane sweep over the neighbouring photos before
# fusing (geometry.photo_consistency). On the development scenes (buu and shrub, both modes,
# holdout, the mean of the four; PSNR / SSIM / PSNR at mean grey / sharpness), `balanced` scored
# 20.63 / 0.649 / 21.33 / 0.78 without it; with windows of 5x5 and 31 depths within +-15 %
# 20.94 / 0.681 / 21.68 / 0.82, but buu's low-light row lost 0.06 dB (the noise the operator
# amplifies in its darkest photos; a score of at least 0.7 instead of 0.5: 20.95 / 0.680, buu's
# row unchanged); 7x7 windows 21.01 / 0.682 / 21.79 / 0.82 (buu low light +0.20 dB), 9x9 21.01 /
# 0.682 and shrub's over-exposed row lower; 7x7 with 15 depths, 2 % apart (the parabola between),
# 21.00 / 0.681 in half the time: about 2 s for 32 views of 224x168 on 2 cores. 3 neighbours
# instead of 4 lost 0.03 dB. `fast` gains as much (buu +0.33 dB in both modes, shrub's low light
# +0.46) for about 1 s of its 13.5 s then. The sweep runs on the CPU, also with --device cuda.
# A new depth must also score 0.5 above the lowest of the swept depths: where views are close
# together for the depth they see, the score hardly changes with depth and its best is noise.
# `make demo`'s 8 photos (buu's every third) place view 22 far from a cluster of four: with no
# such rule its colour chart fell into horizontal streaks (with no sweep it is clean). Asking
# 0.1 above the old depth's score instead (the first rule) cleaned it too but also kept correct
# small moves out (on a textured plane biased 4-8 %, 26 % of pixels stayed over 2 % off, against
# 11 % with the contrast). Development mean (PSNR / SSIM / sharpness): no rule 21.00 / 0.682 /
# 0.82 with streaks; 0.1 gain 20.84 / 0.669 / 0.80; contrast 0.3 20.98 / 0.680 / 0.815 and 0.4
# 20.95 / 0.677 / 0.81, both with view 22's top row of patches smeared; 0.5 20.92 / 0.674 / 0.81,
# every one of the four rows above the 0.1 gain's, view 22 nearly as clean as with the gain (its
# top row's orange patch a little broken). Without the sweep: 20.63 / 0.649 / 0.78. `best`, whose
# 200 steps might have smoothed what a looser rule places, scored 20.99 / 0.722 / 0.885 at 0.3
# against 20.94 / 0.718 / 0.88 at 0.5, but its view 22 then showed the chart's left edge ragged
# with orange specks (clean at 0.5): one setting for every preset.
# Wider spans (measured at colour rate 2e-2 and 0.2 SSIM, `balanced`, against 20.92 / 0.684 /
# 0.847) seem to pay: +-25 % 20.98 / 0.692 / 0.86, +-50 % 21.03 / 0.698 / 0.87, +-90 % 21.12 /
# 0.705 / 0.89 (3 % steps score as 2 %). They pay only because the contrast is over every swept depth, so a wider
# span lowers the lowest score and loosens the rule: taken over the inner +-15 % alone, +-50 %
# scores 20.92 / 0.686 / 0.85 (nothing gained). As with a lower contrast, buu's novel views then
# carry dark specks off the chart's edge (+-70 % and more) and view 22 of `make demo` breaks (its
# chart in specks and streaks at +-50 %, its yellow patch broken already at +-25 %); a wide first
# pass that must also gain 0.05 or 0.1 over the current depth's score (then the +-15 % pass)
# scored 20.97 and 20.96 and still broke view 22 (0.2: 20.94); +-50 % keeping only depths that two
# neighbours' swept depths confirm within 1 % left view 22 clean but scored 20.87. So +-15 %
# then (for the span taken now, see the end).
# The neighbours are the nearest cameras that see the view's scene (the point on its axis at its
# median depth) at a triangulation angle of 3-15 degrees (as multi-view stereo selects its source
# views): buu's photos come in pairs 0.1-0.5 degrees apart, whose scores hardly change with depth,
# and view 22 of `make demo` sees its nearest neighbours at 15-27 degrees, where square windows no
# longer cover the same surface. On the development mean (measured at 0.3 SSIM, against 20.91 /
# 0.685 / 21.71 / 0.857 with the nearest four at any angle), `balanced`: 1-12 degrees 21.00 /
# 0.692 / 21.83 / 0.865, 0.5-12 20.98, 2-12 21.02, 2-10 21.01, 3-12 21.06 / 0.694 / 21.94 / 0.866,
# 4-12 21.07 (shrub's over-exposed row below the nearest four's: 17.84 against 17.86), 1-15 21.00,
# 3-15 21.06 / 0.695 / 21.95 / 0.866 with every one of the four rows above the nearest four's (buu
# low light 24.85 -> 25.16 dB), so 3-15; `fast` 20.53 / 0.612 -> 20.59 / 0.616. View 22 of `make
# demo` sweeps against one neighbour (15 degrees) and its chart is cleaner than before (its top
# row's orange patch whole). With the angles the contrast rule could not be loosened: 0.3 at 1-12
# degrees scored 21.06 but broke view 22's chart edge into specks (0.2 too). A test of the second
# best peak (the best score 0.05-0.15 above every other local maximum, contrast 0-0.3, nearest
# four) scored 20.96-21.00 and broke view 22 as well; the six nearest neighbours 21.04 / 0.695.
# The span, with the angles (`balanced`, 2 % steps unless said): +-20 % 21.11 / 0.700, +-25 %
# 21.14 / 0.703 / 22.05 / 0.88 (17 depths, 3 % apart: 21.15 / 0.704), +-30 % 21.15 (21 depths:
# 21.16 / 0.706), +-40 % (27 depths) 21.17 / 0.708, +-50 % (33) 21.18 / 0.709 / 22.15 / 0.90; but
# view 22's chart gained specks along its right border already at +-25 % and in its patches at
# +-40 %. With the contrast taken over the inner +-15 % alone, +-25 % scored 21.10 / 0.699: half of
# the gain is the wider span itself, half the contrast it loosens. What makes the wider span safe
# is the neighbours' agreement (`max_disagreement`, as multi-view stereo's fusion checks geometric
# consistency): a new depth stays only where it lands within 2 % of some neighbour's own swept
# depth. +-25 % in 17 depths with it: 21.11 / 0.700 / 22.01 / 0.87 and view 22 as clean as at
# +-15 % (5 %: 21.13 with view 22's specks back; +-40 % with it 21.13 and a few specks; +-15 %
# with it 21.03, so the check alone costs 0.03-0.04 dB on these dense scenes); `fast` 20.59 /
# 0.616 -> 20.62 / 0.619. So +-25 %, 17 depths, 2 %: the sweep takes 2.1 s of `balanced`'s restore
# of buu against 1.4 s over +-15 % (0.9 s of `fast`'s against 0.5 s; restores on one host, not
# interleaved).
DEPTH_SWEEP = DepthSweepSettings()

SFM_BRIGHTENINGS = ("restoration", "tone curve")  # RestorePreset.sfm_brightening


@dataclass(frozen=True)
class RestorePreset:
    name: str
    max_views: int
    resolution: float  # multiplier of the architecture's image size
    sh_degree: int | None  # None: the model's full degree
    voxel_scale: float  # multiple of the pixel footprint a voxel may span (model.pixel_footprint)
    refine_steps: int = 0  # test-time refinement steps (0: the forward pass as it is)
    # at least one step per fitted view, up to twice `refine_steps` (a scene of more views than
    # `refine_steps` takes more steps, so that no view keeps the fusion's errors unfitted; the cap
    # bounds the time of a scene of hundreds of photos); `--refine-steps N` asks for exactly N
    refine_each_view: bool = False
    max_gaussians: int | None = None  # cap on the scene's Gaussians (None: all that the views show)
    gaussian_grid: float = 1.0  # pixel Gaussians per network pixel along each side (pipeline.gaussian_grid)
    sfm_long_side: int = SFM_LONG_SIDE  # the longest side structure-from-motion sees a photo at
    budget_resolution: float = 1.0  # the scale the Gaussian budget's weights are rendered at
    refine_side: int = RefineSettings.max_side  # the longer side of the images refinement fits (never enlarged)
    refine_lr_decay: float = REFINE_LR_DECAY  # the factor refinement's learning rates fall by every 100 steps
    # how far the scene's brightness moves to the key (0: none; None: the mode's own strength,
    # model.appearance.exposure_prior.EXPOSURE_PRIOR_STRENGTH)
    exposure_prior: float | None = None
    # the key the prior pulls towards: "content" (predicted from what the scene shows,
    # model.appearance.exposure_key) or "fixed" (mean sRGB 0.45 for every scene)
    exposure_key: str = "content"
    # fill the rendered views' pixels no Gaussian covers (render.hole_filling); refinement then fits
    # the views as filled (RefineSettings.splat_colours)
    fill_unobserved: bool = True
    denoise_photo: bool = True  # the amplified noise of views restored in 2D removed (model.appearance.amplified_noise)
    densify: DensifySettings | None = None  # refinement's densification schedule (None: the Gaussians it starts from)
    # what structure-from-motion sees: "restoration" (the model's operator: the network runs
    # first) or "tone curve" (the blind curve: structure-from-motion runs beside the network)
    sfm_brightening: str = "restoration"
    # the registered depth refined where neighbouring photos agree (geometry.photo_consistency; None: as aligned)
    depth_sweep: DepthSweepSettings | None = None

    def __post_init__(self) -> None:
        if self.sfm_brightening not in SFM_BRIGHTENINGS:
            raise ValueError(f"sfm_brightening {self.sfm_brightening!r}: use one of {', '.join(SFM_BRIGHTENINGS)}")
        if self.exposure_key not in EXPOSURE_KEYS:
            raise ValueError(f"exposure_key {self.exposure_key!r}: use one of {', '.join(EXPOSURE_KEYS)}")

    def refinement_steps(self, fitted_views: int) -> int:
        """The refinement steps for a scene of `fitted_views` fitted views (`refine_each_view`)."""
        if not self.refine_each_view:
            return self.refine_steps
        return min(max(self.refine_steps, fitted_views), 2 * self.refine_steps)

    def network_image_size(self, model_image_size: int, patch_size: int) -> int:
        """The longer network side: a patch multiple, at least one patch."""
        return max(patch_size, round(model_image_size * self.resolution / patch_size) * patch_size)


# balanced: best's scene (all views up to 32, voxels of one footprint, refinement against the
# photos at their own size) stopped at 45 refinement steps: the first 25 steps take the views from
# sharpness 0.55 to about 0.85. On the development scenes (buu and shrub, both modes, holdout, the
# mean of the four; PSNR / SSIM / PSNR at mean grey / sharpness), with refinement fitting the
# colours the hole fill shows (one evaluation each, 2026-11-27): 35 steps 21.45 / 0.732 / 22.37 /
# 0.93, 45 21.50 / 0.740 / 22.45 / 0.94 (buu low light 25.24 dB against 25.23, shrub low light
# +0.05, buu over-exposed +0.04, shrub over-exposed +0.10), 50 21.54 / 0.744 / 22.50 / 0.95 (buu's
# low light 25.17). The steps cost about 0.25 s each on buu's 25 photos: warm restores of buu
# took 24.8 s at 35 steps and 28.0-29.0 s at 50 (interleaved, one host), and in one run of
# benchmarks/presets.py 28.5 s at 45 and 27.7 s at 50 (docs/performance.md): the issue on speed
# sets 30 s, and 45 keeps about 1-2 s for the hosts' spread. Before that change
# the steps bought SSIM and sharpness only (25 steps 21.11 / 0.700, 35 21.12 / 0.707, 50 21.09 /
# 0.714): fitted over black, the longer fits moved the views away from what the fill shows.
# Voxels of two footprints merge neighbouring pixels of one view into
# Gaussians that do not cover their seams: where only that view sees the scene (the borders of
# `make demo`'s views, the corner of buu's frame 19) the black background showed through as dark
# streaks. The network keeps the model's resolution: at 0.75x it misplaced the 8 photos of 250 px
# of `make demo` into ghosted, doubled views. Structure-from-motion sees photos of at most 384 px
# (`fast`'s size; a view that does not register there gets the 512 px retry): on the development
# scenes (buu and shrub, both modes, holdout, the mean of the four) 20.60 dB / 0.642 / sharpness
# 0.770 against 20.59 / 0.641 / 0.772 at 512 px, every view registered, and each evaluation about
# 4 s shorter; the cameras' median rotation error against the scenes' reference rises from about
# 0.25 to 0.35 degrees (buu and shrub), which `best` keeps at 512 px.
# Every fitted view gets at least one step, up to 90 (`refine_each_view`): with 25 steps, one view each, 5 of
# shrub's 30 fitted views (10 of 35 in the context protocol) stayed as the fusion made them; with
# one step per view all four of shrub's rows rose by 0.03-0.05 dB and 0.012-0.024 SSIM (the mean of
# the four 20.61 / 0.642 / 0.77 -> 20.63 / 0.649 / 0.78; measured at 25 steps).
_BALANCED = RestorePreset("balanced", max_views=32, resolution=1.0, sh_degree=None, voxel_scale=1.0, refine_steps=45,
                          refine_each_view=True, refine_side=512, sfm_long_side=384, depth_sweep=DEPTH_SWEEP)

RESTORE_PRESETS = {
    # fast: a smaller network image without view-dependent colour, 15 refinement steps against
    # the photos at 256 px (on buu's holdout frames, the first measurement with the fixed key: 22.26 dB
    # without refinement, 23.10 with 15 steps, 23.08 with 25 at 10 % more time; in the presets run of
    # 2026-11-27 23.97, 24.73 and 24.60: the first steps are what sharpen the views),
    # structure-from-motion on photos of at most 384 px (on buu and Strecha 0.4 degrees median
    # rotation error against 0.3 at 512, in 40-60 % of the time) and the budget's weights at half
    # resolution (up to 0.08 dB lost). 8 views left buu's holdout scene to 5 photos whose
    # misplaced Gaussians it could not outvote (14.4 dB). On few small photos (make demo's 8 at
    # 250 px) the 0.75x network misplaces views: use balanced there. Structure-from-motion sees the
    # blind tone curve and runs beside the network pass: on the development scenes (buu and shrub,
    # both modes, holdout, the mean of the four) 19.762 dB / 0.5867 against 19.763 / 0.5866 on
    # the restoration, every view registered, buu's holdout evaluation 10.7 -> 8.9 s. `balanced`
    # keeps the restoration: on the tone curve shrub's low-light photos registered 34 of 35 views
    # (-0.10 dB / -0.010 SSIM there) and the mean moved -0.005 dB.
    "fast": RestorePreset("fast", max_views=16, resolution=0.75, sh_degree=0, voxel_scale=1.0, refine_steps=15,
                          sfm_long_side=384, budget_resolution=0.5, sfm_brightening="tone curve", depth_sweep=DEPTH_SWEEP),
    "balanced": _BALANCED,
    # best: the same scene refined for 200 steps (the early stop may end it sooner) and densified
    # (DENSIFY), at the network's trained resolution (1.25x scored 0.3-0.5 dB lower on buu's
    # holdout) and the grid of 1: the grid of 2 refined for 200 decaying steps scored 23.58 dB /
    # 0.884 on buu's holdout against 23.76 / 0.891. On the development scenes (buu and shrub, both
    # modes, holdout, the mean of the four) 200 steps without densification scored 20.09 dB /
    # 0.683 / sharpness 0.83 and with it 20.17 / 0.694 / 0.86 (shrub's foliage gains the most:
    # over-exposed 17.12 / 0.536 / 0.85 -> 17.44 / 0.563 / 0.89). See docs/performance.md for
    # the measured trade. Structure-from-motion at 512 px, for the most accurate cameras. Longer
    # runs on shrub's over-exposed holdout (every step run, the rates falling to a tenth over the
    # run): 300 steps 18.09 / 0.656, 600 steps 18.26 / 0.690, against 18.09 / 0.632 at 200, in 1.4x
    # and 2.8x the refinement's time (docs/model-card.md); 300 steps on the development mean 21.17 /
    # 0.749 / 22.39 / 0.93 against 21.18 / 0.742 / 22.33 / 0.92 (shrub's low light -0.14 dB: the
    # steps fit the noise the operator amplifies): 200.
    "best": replace(_BALANCED, name="best", refine_steps=200, densify=DENSIFY, sfm_long_side=SFM_LONG_SIDE),
}


def _require_whole_number(value, parameter: str) -> None:
    if value is not None and (isinstance(value, bool) or not isinstance(value, numbers.Integral)):
        raise InputError(f"{value!r}: give a whole number", parameter=parameter)


def check_max_views(max_views: int | None) -> None:
    """InputError unless `max_views` (the views the network sees; None: the preset's) is a whole
    number of at least 1 (0 once fell back to the preset's silently; 1.5 failed in torch)."""
    _require_whole_number(max_views, "max_views")
    if max_views is not None and max_views < 1:
        raise InputError(f"{max_views}: use at least 1", parameter="max_views")


def get_restore_preset(
    name: str, refine_steps: int | None = None, max_gaussians: int | None = None, gaussian_grid: float | None = None,
    exposure_prior: float | None = None, fill_unobserved: bool | None = None, denoise_photo: bool | None = None,
    densify: bool | None = None, exposure_key: str | None = None, depth_sweep: bool | None = None,
) -> RestorePreset:
    """The preset `name`, with its refinement steps, Gaussian cap, Gaussian grid, exposure prior,
    hole filling and one-photo denoising replaced by `refine_steps`, `max_gaussians`,
    `gaussian_grid`, `exposure_prior`, `fill_unobserved` and `denoise_photo` when given;
    `densify` True refines with `DENSIFY`'s schedule (or the preset's own), False without;
    `exposure_key` the key the exposure prior pulls towards (EXPOSURE_KEYS); `depth_sweep` True
    refines the registered depth with `DEPTH_SWEEP` (or the preset's own settings), False not."""
    try:
        preset = RESTORE_PRESETS[name]
    except KeyError:
        raise InputError(f"{name!r}: use one of {', '.join(RESTORE_PRESETS)}", parameter="preset") from None
    for parameter, value in (("refine_steps", refine_steps), ("max_gaussians", max_gaussians)):
        _require_whole_number(value, parameter)
    if refine_steps is not None:
        if refine_steps < 0:
            raise InputError(f"{refine_steps}: use 0 (no refinement) or more steps", parameter="refine_steps")
        preset = replace(preset, refine_steps=refine_steps, refine_each_view=False)
    if max_gaussians is not None:
        if max_gaussians < 1:
            raise InputError(f"{max_gaussians}: use at least 1 Gaussian", parameter="max_gaussians")
        preset = replace(preset, max_gaussians=max_gaussians)
    if gaussian_grid is not None:
        if not 1 <= gaussian_grid <= 4:
            raise InputError(f"{gaussian_grid}: use 1 (the network's grid) to 4", parameter="gaussian_grid")
        preset = replace(preset, gaussian_grid=gaussian_grid)
    if exposure_prior is not None:
        if not 0 <= exposure_prior <= 1:
            raise InputError(f"{exposure_prior}: use 0 (the model's own exposure) to 1 (the key's)", parameter="exposure_prior")
        preset = replace(preset, exposure_prior=exposure_prior)
    if exposure_key is not None:
        if exposure_key not in EXPOSURE_KEYS:
            raise InputError(f"{exposure_key!r}: use one of {', '.join(EXPOSURE_KEYS)}", parameter="exposure_key")
        preset = replace(preset, exposure_key=exposure_key)
    if fill_unobserved is not None:
        preset = replace(preset, fill_unobserved=fill_unobserved)
    if denoise_photo is not None:
        preset = replace(preset, denoise_photo=denoise_photo)
    if densify is not None:
        preset = replace(preset, densify=(preset.densify or DENSIFY) if densify else None)
    if depth_sweep is not None:
        preset = replace(preset, depth_sweep=(preset.depth_sweep or DEPTH_SWEEP) if depth_sweep else None)
    return preset
