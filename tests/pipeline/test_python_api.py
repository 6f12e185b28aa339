"""The package's Python API does what the command line does, without the CLI."""

import json
import shutil
from types import ModuleType

import lumos3d_cli
import pytest
from plyfile import PlyData

from lumos3d_cli.errors import InputError


def test_every_exported_name_resolves_to_what_it_names_even_after_the_jobs_are_imported():
    import lumos3d_cli.pipeline.restore  # imports the subpackage `render`, which Python binds on the package
    from lumos3d_cli.render.render import render

    for name in lumos3d_cli.__all__:
        value = getattr(lumos3d_cli, name)
        assert value is not None and not isinstance(value, ModuleType), name
    assert lumos3d_cli.render_gaussians is render


def test_restore_and_write_without_the_cli(buu, tmp_path, random_checkpoint):
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in ("4.JPG", "5.JPG"):
        shutil.copy(buu / "low" / name, photos / name)
    scene = lumos3d_cli.restore(photos, checkpoint=random_checkpoint, geometry="network", reference=buu / "high",
                                refine_steps=0)
    assert scene.names == ["4.JPG", "5.JPG"] and [tuple(view.shape) for view in scene.restored] == [(3, 375, 500)] * 2
    assert scene.metrics["mean"]["psnr"] > 0 and scene.geometry.source == "network"
    summary = lumos3d_cli.write_restored_scene(scene, tmp_path / "out" / "scene.ply")
    assert json.loads((tmp_path / "out" / "summary.json").read_text()) == json.loads(json.dumps(summary))
    assert PlyData.read(str(tmp_path / "out" / "scene.ply"))["vertex"].count == len(scene.gaussians)
    assert sorted(p.name for p in (tmp_path / "out" / "restored").iterdir()) == ["4.png", "5.png"]
    # written again: the same outputs, the total counting one write
    total = summary["seconds"]["total"] - summary["seconds"]["write"]
    again = lumos3d_cli.write_restored_scene(scene, tmp_path / "out" / "scene.ply")
    assert again["seconds"]["total"] == pytest.approx(total + again["seconds"]["write"], abs=2e-3)  # rounded to ms
    # never into the folder the photos were read from, as `lumos3d restore` refuses it
    with pytest.raises(InputError, match="is the input folder"):
        lumos3d_cli.write_restored_scene(scene, photos / "scene.ply")
    with pytest.raises(InputError) as caught:
        lumos3d_cli.write_restored_scene(scene, tmp_path / "out2" / "scene.ply", video=tmp_path / "orbit.avi")
    assert caught.value.parameter == "video" and str(caught.value) == f"video {tmp_path / 'orbit.avi'}: the file name must end in .mp4 (H.264) or .gif"
    assert sorted(p.name for p in photos.iterdir()) == ["4.JPG", "5.JPG"] and not (tmp_path / "out2").exists()


def test_library_errors_name_parameters_not_flags(buu, random_checkpoint):
    with pytest.raises(InputError) as caught:
        lumos3d_cli.restore(buu / "low", checkpoint=random_checkpoint, preset="ultra")
    assert caught.value.parameter == "preset" and str(caught.value).startswith("preset 'ultra'")
    assert "--" not in str(caught.value)
    with pytest.raises(InputError, match="^geometry 'colmap': use one of auto, network, sfm$"):
        lumos3d_cli.restore(buu / "low", checkpoint=random_checkpoint, geometry="colmap")


def test_a_photo_batch_made_in_python_with_nan_names_the_photo(buu, random_checkpoint):
    import torch

    from lumos3d_cli.io.images import load_images
    from lumos3d_cli.model.loading import load_model
    from lumos3d_cli.pipeline.presets import get_restore_preset
    from lumos3d_cli.pipeline.restore import restore_scene

    batch = load_images([buu / "low" / name for name in ("1.JPG", "2.JPG", "3.JPG")])
    batch.images[1, 0, 5, 5] = torch.nan
    with pytest.raises(InputError, match=r"low/2.JPG: the photo's pixels hold NaN or Inf"):
        restore_scene(batch, load_model(random_checkpoint), get_restore_preset("fast"), geometry="network")
