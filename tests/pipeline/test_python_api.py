"""The package's Python API does what the command line does, without the CLI."""

import json
import shutil
from types import ModuleType

import cv2
import lumos3d_cli
import pytest
from plyfile import PlyData

from lumos3d_cli.errors import InputError, NonFiniteError


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


def test_a_scene_edited_in_python_is_written_or_refused_naming_the_view(buu, tmp_path, random_checkpoint):
    """A bfloat16 view failed in numpy; a NaN one was blamed on a temporary file in the staging folder."""
    import torch

    scene = lumos3d_cli.restore([buu / "low" / "4.JPG"], checkpoint=random_checkpoint, geometry="network", refine_steps=0)
    view = scene.restored[0]
    scene.restored[0] = view.to(torch.bfloat16)
    lumos3d_cli.write_restored_scene(scene, tmp_path / "out" / "scene.ply")
    written = cv2.imread(str(tmp_path / "out" / "restored" / "4.png"))[..., ::-1] / 255
    expected = view.to(torch.bfloat16).float().permute(1, 2, 0).numpy()
    assert abs(written - expected).max() <= 0.5 / 255 + 1e-6
    scene.restored[0] = view.clone()
    scene.restored[0][0, 1, 2] = torch.nan
    with pytest.raises(NonFiniteError, match=r"^restored view 4.JPG: 1 of \d+ values are NaN or Inf"):
        lumos3d_cli.write_restored_scene(scene, tmp_path / "out2" / "scene.ply")
    assert not (tmp_path / "out2").exists()


def test_library_errors_name_parameters_not_flags(buu, random_checkpoint):
    with pytest.raises(InputError) as caught:
        lumos3d_cli.restore(buu / "low", checkpoint=random_checkpoint, preset="ultra")
    assert caught.value.parameter == "preset" and str(caught.value).startswith("preset 'ultra'")
    assert "--" not in str(caught.value)
    with pytest.raises(InputError, match="^geometry 'colmap': use one of auto, network, sfm$"):
        lumos3d_cli.restore(buu / "low", checkpoint=random_checkpoint, geometry="colmap")


@pytest.mark.parametrize("max_views", [0, 1.5, "2", True])
def test_max_views_must_be_a_whole_number_of_at_least_one(buu, random_checkpoint, max_views):
    """1.5 and "2" failed in torch.linspace and a comparison, after the photos were read."""
    for job in (lambda: lumos3d_cli.restore(buu / "low", checkpoint=random_checkpoint, max_views=max_views),
                lambda: lumos3d_cli.evaluate_lom(buu.parent, ["buu"], checkpoint=random_checkpoint, max_views=max_views)):
        with pytest.raises(InputError) as caught:
            job()
        assert caught.value.parameter == "max_views"


def test_a_float64_default_dtype_is_refused_before_the_work(buu, random_checkpoint):
    """torch.set_default_dtype(torch.float64) made tensors the photos' float32 did not match: a
    scatter error in the network's histograms."""
    import torch

    torch.set_default_dtype(torch.float64)
    try:
        with pytest.raises(InputError, match=r"default dtype is torch.float64; .* torch.set_default_dtype\(torch.float32\)"):
            lumos3d_cli.restore(buu / "low", checkpoint=random_checkpoint, geometry="network")
    finally:
        torch.set_default_dtype(torch.float32)


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
