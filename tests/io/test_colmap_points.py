import pycolmap
import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.colmap import read_colmap_model, sparse_points_of, write_colmap_model

from synthetic_scene import plane_cameras, plane_points


def _read_points(folder, names):
    """The model's points through pycolmap, their views indexing `names` (as structure-from-motion reads them)."""
    reconstruction = pycolmap.Reconstruction(folder)
    return sparse_points_of(reconstruction, {image_id: names.index(image.name)
                                             for image_id, image in reconstruction.images.items()})


def _observation_set(points):
    return sorted(zip(points.view.tolist(), points.point.tolist(), [tuple(round(v, 9) for v in p) for p in points.pixel.tolist()]))


def test_points_with_tracks_round_trip_and_open_in_colmap(tmp_path):
    cameras = plane_cameras(4)
    points = plane_points(cameras, 50)
    write_colmap_model(tmp_path, cameras, points)
    back = _read_points(tmp_path, read_colmap_model(tmp_path).names)
    torch.testing.assert_close(back.xyz, points.xyz, atol=0, rtol=0)
    assert torch.equal(back.rgb, points.rgb)
    assert _observation_set(back) == _observation_set(points)
    reconstruction = pycolmap.Reconstruction(tmp_path)  # COLMAP itself accepts the model
    assert reconstruction.num_points3D() == 50 and reconstruction.compute_num_observations() == len(points.view)
    # the written observations are where COLMAP projects the points: a consistent model
    assert reconstruction.compute_mean_reprojection_error() < 1e-6


def test_binary_model_reads_like_its_text_form(buu):
    text = read_colmap_model(buu / "colmap_text")
    binary = read_colmap_model(buu / "colmap_sparse" / "0")
    torch.testing.assert_close(binary.extrinsics, text.extrinsics, atol=1e-12, rtol=0)
    torch.testing.assert_close(binary.intrinsics, text.intrinsics, atol=0, rtol=0)
    points = _read_points(buu / "colmap_sparse" / "0", binary.names)
    pixels, depth = binary.project(points.xyz)
    assert (depth[points.view, points.point] > 0).all()
    # observations sit where the model's cameras project their points (distortion ignored)
    assert float((pixels[points.view, points.point] - points.pixel).norm(dim=1).median()) < 2.0


def test_unreadable_model_is_an_input_error(tmp_path):
    (tmp_path / "cameras.bin").write_bytes(b"garbage")
    (tmp_path / "images.bin").write_bytes(b"garbage")
    with pytest.raises(InputError):
        read_colmap_model(tmp_path)


def test_a_point_that_is_not_a_position_is_refused_by_its_id(tmp_path):
    """A NaN point reached the viewer's browser and training's depth supervision unnamed."""
    from lumos3d_cli.io.colmap import read_colmap_points

    (tmp_path / "points3D.txt").write_text("# 2 points\n1 0.5 0.25 2.0 10 20 30 0.4 1 0\n7 nan 0 1 10 20 30 0.4 1 1\n")
    with pytest.raises(InputError, match=r"points3D.txt: point 7 lies at nan 0 1, which is not a position"):
        read_colmap_points(tmp_path / "points3D.txt")
