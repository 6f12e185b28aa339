"""The denser grid of pixel Gaussians (pipeline.gaussian_grid)."""

import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.sparse_points import SparsePoints
from lumos3d_cli.model.geometry import unproject_depth
from lumos3d_cli.model.lumos3d import Lumos3DPrediction
from lumos3d_cli.pipeline.gaussian_grid import dense_grid_size, densify_grid, upsample_depth
from lumos3d_cli.pipeline.scene_geometry import SceneGeometry


def test_the_dense_grid_never_exceeds_the_photos():
    assert dense_grid_size((224, 168), (500, 375), 2.0) == (448, 336)
    assert dense_grid_size((280, 210), (500, 375), 2.0) == (500, 375)  # capped at the photo
    assert dense_grid_size((224, 168), (200, 150), 2.0) == (224, 168)  # never coarser than the network
    assert dense_grid_size((224, 168), (500, 375), 1.0) == (224, 168)


def test_depth_is_smooth_on_surfaces_and_keeps_its_edges():
    ramp = torch.linspace(1.0, 1.2, 8, dtype=torch.float64)[None, None, :].expand(1, 6, 8)
    dense = upsample_depth(ramp, (16, 12))
    # inside, bilinear interpolation of a linear ramp is the ramp at the finer pixel centres
    centres = (torch.arange(16, dtype=torch.float64) + 0.5) / 2 - 0.5
    expected = 1.0 + 0.2 / 7 * centres
    torch.testing.assert_close(dense[0, 5, 2:-2], expected[2:-2])
    step = torch.ones(1, 6, 8)
    step[..., 4:] = 5.0  # a foreground edge in front of a far wall
    dense = upsample_depth(step, (16, 12))
    assert set(dense.unique().tolist()) == {1.0, 5.0}  # nothing floats between them


def _scene(views: int = 2, size: tuple[int, int] = (8, 6), depth: float = 2.0):
    width, height = size
    intrinsics = torch.tensor([[7.0, 0, 4.2], [0, 7.5, 2.9], [0, 0, 1]], dtype=torch.float64).expand(views, 3, 3).clone()
    extrinsics = torch.eye(3, 4, dtype=torch.float64).expand(views, 3, 4).clone()
    extrinsics[1, 0, 3] = 0.3
    depth_map = torch.full((views, height, width), depth, dtype=torch.float64)
    params = torch.randn(1, views, height, width, 20, generator=torch.Generator().manual_seed(0))
    prediction = Lumos3DPrediction([torch.zeros(1, views, 9)], extrinsics[None].float(), intrinsics[None].float(),
                                   depth_map[None].float(), torch.ones(1, views, height, width), params,
                                   torch.zeros(1, views, height, width))
    fuse = torch.ones(views, height, width, dtype=torch.bool)
    fuse[0, :, :4] = False
    cameras = Cameras(extrinsics, intrinsics, [size] * views, [f"{i}.png" for i in range(views)])
    geometry = SceneGeometry("network", cameras, extrinsics, intrinsics, depth_map, SparsePoints.empty(), {}, fuse)
    return prediction, geometry


def test_the_dense_grid_samples_the_same_surface_at_finer_pixels():
    prediction, geometry = _scene()
    dense_prediction, dense = densify_grid(prediction, geometry, (16, 12))
    assert dense.depth.shape == (2, 12, 16) and dense_prediction.params.shape == (1, 2, 12, 16, 20)
    assert dense_prediction.confidence.shape == dense_prediction.depth_conf.shape == (1, 2, 12, 16)
    points = unproject_depth(dense.depth, dense.network_extrinsics, dense.network_intrinsics)
    # the fine pixel centres, seen through the coarse camera, fall at (j + 0.5) / 2 coarse pixels
    camera = torch.einsum("vij,vhwj->vhwi", geometry.network_extrinsics[:, :, :3], points) + geometry.network_extrinsics[:, None, None, :, 3]
    u = geometry.network_intrinsics[:, 0, 0, None, None] * camera[..., 0] / camera[..., 2] + geometry.network_intrinsics[:, 0, 2, None, None]
    v = geometry.network_intrinsics[:, 1, 1, None, None] * camera[..., 1] / camera[..., 2] + geometry.network_intrinsics[:, 1, 2, None, None]
    torch.testing.assert_close(u[0, 0], (torch.arange(16, dtype=torch.float64) + 0.5) / 2)
    torch.testing.assert_close(v[1, :, 0], (torch.arange(12, dtype=torch.float64) + 0.5) / 2)
    assert torch.equal(dense.fuse_pixels[0, :, :8], torch.zeros(12, 8, dtype=torch.bool)) and dense.fuse_pixels[0, :, 8:].all()
    assert dense.cameras is geometry.cameras  # the views' own cameras do not change


def test_a_grid_of_the_network_size_is_the_prediction_itself():
    prediction, geometry = _scene()
    assert densify_grid(prediction, geometry, (8, 6)) == (prediction, geometry)
