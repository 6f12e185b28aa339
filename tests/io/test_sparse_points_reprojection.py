import math

import torch

from lumos3d_cli.io.cameras import Cameras, make_intrinsics
from lumos3d_cli.io.sparse_points import SparsePoints


def test_reprojection_errors_are_measured_against_the_given_cameras():
    """Points carried onto given poses keep SfM's pixels: their error is where the given cameras
    put them against where they were seen (one point 3 px off in one of its two views)."""
    extrinsics = torch.eye(3, 4, dtype=torch.float64)[None].repeat(2, 1, 1)
    extrinsics[1, 0, 3] = -1.0  # the second camera one unit to the right
    cameras = Cameras(extrinsics, make_intrinsics([100.0, 100.0], [100.0, 100.0], [50.0, 50.0], [40.0, 40.0]),
                      [(100, 80)] * 2)
    xyz = torch.tensor([[0.0, 0.0, 5.0], [1.0, 0.5, 4.0]], dtype=torch.float64)
    view = torch.tensor([0, 1, 0, 1])
    point = torch.tensor([0, 0, 1, 1])
    exact = torch.tensor([[50.0, 40.0], [30.0, 40.0], [75.0, 52.5], [50.0, 52.5]], dtype=torch.float64)
    pixel = exact + torch.tensor([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [3.0, 0.0]], dtype=torch.float64)
    points = SparsePoints(xyz, torch.zeros(2, 3, dtype=torch.uint8), torch.zeros(2, dtype=torch.float64), view, point, pixel)
    measured, mean = points.reprojected(cameras)
    torch.testing.assert_close(measured.error, torch.tensor([0.0, 1.5], dtype=torch.float64))
    assert mean == 3.0 / 4
    assert math.isnan(SparsePoints.empty().reprojected(cameras)[1])
