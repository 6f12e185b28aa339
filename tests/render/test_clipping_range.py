import pytest
import torch
from assertions import expect_input_error
from factories import camera_at_origin, random_scene

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.io.ply import write_ply
from lumos3d_cli.render.clipping_range import require_drawable
from lumos3d_cli.render.render import render


def _scaled(gaussians: Gaussians, factor: float) -> Gaussians:
    return Gaussians(gaussians.means * factor, gaussians.quats, gaussians.scales * factor, gaussians.opacities, gaussians.sh)


@pytest.mark.parametrize("factor", [1e-6, 1e12])
def test_a_scene_outside_the_clipping_range_is_refused_where_its_render_would_be_black(factor):
    camera = camera_at_origin(64, 48)
    scene = random_scene(200, 0)
    require_drawable(scene.means, camera, "scene.ply")  # 3 units ahead: drawn
    assert float(render(scene, camera).alphas.max()) > 0.5
    far_off = _scaled(scene, factor)
    assert float(render(far_off, camera).alphas.max()) == 0.0  # the oracle: nothing is drawn
    with pytest.raises(InputError, match=r"scene.ply: no camera sees the scene: it lies [23]\.\d+e[-+]\d+ units in front"):
        require_drawable(far_off.means, camera, "scene.ply")


def test_a_scene_behind_every_camera_is_named_so_and_a_partly_drawable_one_passes():
    camera = camera_at_origin(64, 48)
    behind = random_scene(50, 1)
    behind.means[:, 2] *= -1
    with pytest.raises(InputError, match="behind every camera .*check that the cameras face the scene") as refused:
        require_drawable(behind.means, camera)
    assert "units" not in str(refused.value)  # the remedy is the orientation, not the units
    mixed = torch.cat([behind.means, torch.tensor([[0.0, 0.0, 2.0]], dtype=torch.float64)])
    require_drawable(mixed, camera)


def test_render_refuses_a_micro_scale_scene_naming_the_file(run_cli, tmp_path):
    scene = tmp_path / "tiny.ply"
    write_ply(scene, _scaled(random_scene(300, 2, degree=0), 1e-6))
    output = tmp_path / "frames"
    expect_input_error(run_cli("render", scene, "--orbit", 2, "-o", output), f"{scene}: no camera sees the scene")
    assert not output.exists()

