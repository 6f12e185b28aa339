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
