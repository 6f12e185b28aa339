import math

import numpy as np
import pytest
import torch

from lumos3d_cli.eval.pose_accuracy import area_under_curve, pose_accuracy, relative_pose_errors
from lumos3d_cli.rotations import quaternion_to_matrix


def _random_cameras(count: int, seed: int) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    rotations = quaternion_to_matrix(torch.randn(count, 4, generator=generator, dtype=torch.float64))
    centres = torch.randn(count, 3, generator=generator, dtype=torch.float64)
    return torch.cat((rotations, -(rotations @ centres[..., None])), dim=-1)


def _rotation_about_z(degrees: float) -> torch.Tensor:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return torch.tensor([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=torch.float64)


def test_a_similarity_transform_of_the_world_changes_nothing():
    cameras = _random_cameras(6, seed=0)
    world = _rotation_about_z(33.0) @ quaternion_to_matrix(torch.tensor([0.9, 0.1, -0.3, 0.2], dtype=torch.float64))
    scale, shift = 7.5, torch.tensor([1.0, -2.0, 3.0], dtype=torch.float64)
    # x_world' = scale * world @ x + shift: R' = R world^T, t' = scale * t - R' shift
    rotations = cameras[:, :, :3] @ world.T
    moved = torch.cat((rotations, scale * cameras[:, :, 3:] - rotations @ shift[:, None]), dim=-1)
    rotation_error, translation_error = relative_pose_errors(moved, cameras)
    assert rotation_error.shape == (15,)
    assert rotation_error.abs().max() < 1e-6 and translation_error.abs().max() < 1e-5
    summary = pose_accuracy(moved, cameras)
    assert summary.auc_30 == 1.0 and summary.rra_15 == 1.0 and summary.rta_15 == 1.0 and summary.pairs == 15


def test_errors_match_an_independent_computation_from_camera_centres():
    reference, predicted = _random_cameras(5, seed=1), _random_cameras(5, seed=2)
    rotation_error, translation_error = relative_pose_errors(predicted, reference)
    expected_rotation, expected_translation = [], []
    for i in range(5):
        for j in range(i + 1, 5):
            directions, relatives = [], []
            for cameras in (predicted.numpy(), reference.numpy()):
                rotation = [cameras[k, :, :3] for k in (i, j)]
                centre = [-cameras[k, :, :3].T @ cameras[k, :, 3] for k in (i, j)]
                relatives.append(rotation[1] @ rotation[0].T)
                directions.append(rotation[1] @ (centre[0] - centre[1]))  # camera i's centre seen from j
            cosine = (np.trace(relatives[0].T @ relatives[1]) - 1) / 2
            expected_rotation.append(math.degrees(math.acos(np.clip(cosine, -1, 1))))
            a, b = directions
            angle = math.degrees(math.acos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))
            expected_translation.append(min(angle, 180 - angle))
    np.testing.assert_allclose(rotation_error.numpy(), expected_rotation, atol=1e-6)
    np.testing.assert_allclose(translation_error.numpy(), expected_translation, atol=1e-6)


def test_a_known_rotation_error():
    reference = torch.zeros(3, 3, 4, dtype=torch.float64)
    centres = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=torch.float64)
    reference[:, :, :3] = torch.eye(3, dtype=torch.float64)
    reference[:, :, 3] = -centres
    predicted = reference.clone()
    predicted[2, :, :3] = _rotation_about_z(20.0)
    predicted[2, :, 3] = -(predicted[2, :, :3] @ centres[2])  # same centre, turned about its axis
    rotation_error, translation_error = relative_pose_errors(predicted, reference)
    np.testing.assert_allclose(rotation_error.numpy(), [0.0, 20.0, 20.0], atol=1e-9)
    # camera 2 sees the others' centres turned by 20 degrees about its optical axis
    np.testing.assert_allclose(translation_error.numpy(), [0.0, 20.0, 20.0], atol=1e-9)
    summary = pose_accuracy(predicted, reference)
    assert summary.rra_15 == pytest.approx(1 / 3) and summary.rotation_error_median == pytest.approx(20.0)
    assert summary.auc_30 == pytest.approx((30 + 2 * 10) / 90)


def test_area_under_curve():
    assert area_under_curve(torch.tensor([0.5, 5.0, 40.0]), 30) == pytest.approx((30 + 25 + 0) / 90)
    assert area_under_curve(torch.tensor([0.0]), 30) == 1.0


def test_degenerate_and_bad_inputs():
    reference = _random_cameras(3, seed=3)
    collapsed = reference.clone()
    collapsed[:, :, 3] = 0.0  # every camera at the origin: no translation direction
    collapsed[:, :, :3] = torch.eye(3, dtype=torch.float64)
    rotation_error, translation_error = relative_pose_errors(collapsed, reference)
    assert torch.isfinite(rotation_error).all() and (translation_error == 90).all()
    with pytest.raises(ValueError, match="at least two views"):
        pose_accuracy(reference[:1], reference[:1])
    with pytest.raises(ValueError, match="expected two extrinsics"):
        relative_pose_errors(reference, reference[:2])
    broken = reference.clone()
    broken[1, 0, 3] = float("nan")
    with pytest.raises(ValueError, match="non-finite"):
        pose_accuracy(broken, reference)
