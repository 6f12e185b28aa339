import pytest
import torch

from lumos3d_cli.errors import NonFiniteError
from lumos3d_cli.model.loading import load_model
from lumos3d_cli.pipeline.network_pass import run_network
from lumos3d_cli.pipeline.presets import get_restore_preset


def test_weights_that_give_nan_on_the_photos_are_named_before_the_geometry_meets_it(random_checkpoint):
    """Finite weights, scaled until the depth head overflows: once refused as "depth: N values are
    NaN" from the depth checks downstream, naming neither the checkpoint nor what to do."""
    model = load_model(random_checkpoint)
    photos = torch.rand(2, 3, 84, 112, generator=torch.Generator().manual_seed(0))
    run_network(model, photos, get_restore_preset("fast"))  # the weights as they are: finite
    with torch.no_grad():
        for name, parameter in model.named_parameters():
            if name.startswith("depth_head"):
                parameter.mul_(1e30)
    with pytest.raises(NonFiniteError, match=rf"the network's \w+: .*NaN or Inf; {random_checkpoint} gives NaN/Inf "
                                              "on these photos: damaged or diverged weights; use another checkpoint"):
        run_network(model, photos, get_restore_preset("fast"))


@pytest.mark.parametrize("level", [0.0, 1.0])
def test_an_all_black_or_white_photo_changes_nothing_in_the_others_restoration(buu, level):
    """The illumination head read an empty photo as part of the scene: one white photo among four
    darkened the others' restoration by a quarter (4 dB), one black photo brightened it."""
    from lumos3d_cli.io.images import load_images

    model = load_model("low-light")
    photos = load_images([buu / "low" / f"{name}.JPG" for name in ("1", "10", "13", "16")]).images
    preset = get_restore_preset("fast")
    alone = run_network(model, photos, preset).prediction.appearance
    empty = torch.full_like(photos[:1], level)
    joined = run_network(model, torch.cat([photos[:2], empty, photos[2:]]), preset).prediction.appearance
    torch.testing.assert_close(joined.curve_slopes, alone.curve_slopes, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(joined.matrix, alone.matrix, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(joined.local_log2_gain[:, [0, 1, 3, 4]], alone.local_log2_gain, atol=1e-5, rtol=1e-5)
    assert joined.local_log2_gain[:, 2].abs().max() == 0  # the empty view's own: no local correction
