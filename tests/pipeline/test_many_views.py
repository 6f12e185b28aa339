"""Sixty-four photos through the whole restore job with an operator model: every view gets a
camera and a restored view, and nothing non-finite escapes (issue 15's extremes: 64 views)."""

import cv2
import pytest
import torch

import lumos3d_cli
from lumos3d_cli.model.checkpoints import save_checkpoint
from lumos3d_cli.model.lumos3d import build_model


@pytest.mark.slow  # about 50 s on 2 cores
def test_sixty_four_views_restore_end_to_end(buu, tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    sources = sorted((buu / "low").glob("*.JPG"))
    for index in range(64):
        image = cv2.imread(str(sources[index % len(sources)]))
        # a different crop for each repeat of a photo, so no two of the 64 are the same
        top, left = 6 * (index // len(sources)), 8 * (index // len(sources))
        cv2.imwrite(str(photos / f"{index:02d}.png"), cv2.resize(image[top:, left:], (96, 72), interpolation=cv2.INTER_AREA))
    checkpoint = tmp_path / "tiny-operator.safetensors"
    save_checkpoint(build_model("tiny-operator", seed=0), checkpoint, {"weights": "random, for tests"})
    scene = lumos3d_cli.restore(photos, checkpoint=checkpoint, geometry="network", preset="fast", max_views=64,
                                refine_steps=2)
    assert len(scene.selected) == 64 and len(scene.cameras) == 64 and len(scene.restored) == 64
    assert all(view.shape == (3, 72, 96) and bool(torch.isfinite(view).all()) for view in scene.restored)
    assert all(0 <= float(view.min()) and float(view.max()) <= 1 for view in scene.restored)
    gaussians = scene.gaussians
    assert len(gaussians) > 0
    for tensor in (gaussians.means, gaussians.scales, gaussians.quats, gaussians.opacities, gaussians.sh):
        assert bool(torch.isfinite(tensor).all())
    summary = lumos3d_cli.write_restored_scene(scene, tmp_path / "out" / "scene.ply")
    assert summary["refinement"]["steps"] == 2 and len(list((tmp_path / "out" / "restored").iterdir())) == 64
