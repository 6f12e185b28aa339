"""RefineSettings refuses values that cannot run."""

import pytest

from lumos3d_cli.refine.settings import RefineSettings


@pytest.mark.parametrize("change", [{"max_side": 10}, {"steps": -1}, {"views_per_step": 0}, {"positions": "rays"},
                                    {"ssim_weight": 1.5}, {"patience": 0}, {"tolerance": -0.1},
                                    {"lr_decay_per_100_steps": 0.0}, {"lr_decay_per_100_steps": 1.5}])
def test_settings_reject_values_that_cannot_run(change):
    with pytest.raises(ValueError):
        RefineSettings(**change)

