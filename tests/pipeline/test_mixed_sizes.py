"""Photos of different sizes through the Python API: every view keeps its own size, metrics are
taken per view against references of the same sizes."""

import math

import cv2
import numpy as np
import pytest
import torch

import lumos3d_cli
from lumos3d_cli.errors import InputError
from lumos3d_cli.pipeline.quality import QualityMeter, load_references

CROP = (slice(None), slice(100, 400))  # 500x375 -> the middle 300x375


def _scene_folder(buu, folder, light):
    """buu's 4.JPG and 5.JPG as they are, 6.JPG cropped to 300x375."""
    folder.mkdir()
    for name in ("4", "5"):
        cv2.imwrite(str(folder / f"{name}.png"), cv2.imread(str(buu / light / f"{name}.JPG")))
    cv2.imwrite(str(folder / "6.png"), cv2.imread(str(buu / light / "6.JPG"))[CROP])
    return folder


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return 10 * math.log10(1 / float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


def test_network_cameras_views_and_metrics_keep_each_photos_size(buu, tmp_path, random_checkpoint):
    photos = _scene_folder(buu, tmp_path / "photos", "low")
    references = _scene_folder(buu, tmp_path / "references", "high")
    scene = lumos3d_cli.restore(photos, checkpoint=random_checkpoint, geometry="network", reference=references,
                                refine_steps=0)
    sizes = [(500, 375), (500, 375), (300, 375)]
    assert scene.names == ["4.png", "5.png", "6.png"] and scene.cameras.sizes == sizes
    assert [tuple(view.shape) for view in scene.restored] == [(3, h, w) for w, h in sizes]
    assert [tuple(view.shape) for view in scene.inputs] == [(3, h, w) for w, h in sizes]
    # The network's centred principal point is the middle of each photo, whatever its size.
    centres = torch.tensor([[w / 2, h / 2] for w, h in sizes], dtype=scene.cameras.intrinsics.dtype)
    torch.testing.assert_close(scene.cameras.intrinsics[:, :2, 2], centres)
    # The input shown for the crop is the crop as decoded (not squeezed, nor stretched there and back).
    crop = cv2.imread(str(photos / "6.png"))[..., ::-1].astype(np.float32) / 255
    assert np.array_equal(scene.inputs[2].permute(1, 2, 0).numpy(), crop)
    for index, name in enumerate(scene.names):
        reference = cv2.imread(str(references / name))[..., ::-1].astype(np.float64) / 255
        expected = _psnr(scene.restored[index].permute(1, 2, 0).numpy(), reference)
        assert scene.metrics["views"][name]["psnr"] == pytest.approx(expected, abs=1e-3)
    lumos3d_cli.write_restored_scene(scene, tmp_path / "out" / "scene.ply")
    written = {p.name: cv2.imread(str(p)).shape[:2] for p in (tmp_path / "out" / "restored").iterdir()}
    assert written == {"4.png": (375, 500), "5.png": (375, 500), "6.png": (375, 300)}


def test_a_reference_of_another_size_than_its_view_is_named(buu, tmp_path):
    references = _scene_folder(buu, tmp_path / "references", "high")
    assert [tuple(r.shape) for r in load_references(references, ["4.JPG", "6.JPG"], [(500, 375), (300, 375)])] == [
        (3, 375, 500), (3, 375, 300)]
    with pytest.raises(InputError, match=r"6\.png: 300x375, but input 6\.JPG is 500x375; give references of the same"):
        load_references(references, ["4.JPG", "6.JPG"], [(500, 375), (500, 375)])


def test_metrics_of_views_of_different_sizes_are_those_of_each_view_alone():
    generator = torch.Generator().manual_seed(0)
    shapes = [(3, 20, 30), (3, 40, 20), (3, 20, 30)]
    references = [torch.rand(shape, generator=generator) for shape in shapes]
    images = [(r + 0.05 * torch.randn(r.shape, generator=generator)).clamp(0, 1) for r in references]
    meter = QualityMeter.create(None)
    together = meter.measure(images, references)
    alone = [meter.measure(i[None], r[None])[0] for i, r in zip(images, references)]
    for row, expected, image, reference in zip(together, alone, images, references):
        assert row["psnr"] == pytest.approx(-10 * math.log10(float(((image - reference) ** 2).mean())), rel=1e-5)
        assert row["ssim"] == pytest.approx(expected["ssim"], rel=1e-9) and row["lpips"] is None


def test_references_are_matched_by_stem_in_any_case(tmp_path):
    """`restore --reference` found no `view1.jpg` for an input `View1.jpg`, where --poses and eval match in any case."""
    pixels = np.random.default_rng(0).integers(0, 256, (6, 8, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "view1.png"), pixels)
    (reference,) = load_references(tmp_path, ["View1.JPG"], [(8, 6)])
    np.testing.assert_array_equal(reference.permute(1, 2, 0).numpy(), pixels[..., ::-1].astype(np.float32) / 255)
