"""The models shipped in src/lumos3d_cli/weights/: size, storage, provenance, and that they restore."""

import json
from pathlib import Path

import cv2
import pytest
import torch
from safetensors import safe_open

from lumos3d_cli.eval.metrics import ssim
from lumos3d_cli.io.images import load_images
from lumos3d_cli.model.appearance.amplified_noise import MIN_NOISE_LEVEL
from lumos3d_cli.model.bundled_models import BUNDLED_MODELS, bundled_weights_path
from lumos3d_cli.model.checkpoints import summarize_checkpoint
from lumos3d_cli.pipeline.choices import DEFAULT_RESTORE_PRESET
from lumos3d_cli.pipeline.presets import RESTORE_PRESETS

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "lowlight-buu"
WEIGHTS = {mode: bundled_weights_path(name) for mode, name in BUNDLED_MODELS.items()}


def test_the_bundled_models_fit_the_budget_in_half_precision():
    assert all(path.is_file() for path in WEIGHTS.values())
    assert sum(path.stat().st_size for path in WEIGHTS.values()) <= 30 * 2**20
    for mode, path in WEIGHTS.items():
        summary = summarize_checkpoint(path)
        # both predict a restoration operator (issue 15): an illumination head trained on brackets
        assert summary["format"] == "lumos3d" and summary["architecture"] == "tiny-operator"
        assert summary["dtypes"] == {"float16": summary["tensors"]}
        with safe_open(str(path), framework="pt") as f:
            assert all(torch.isfinite(f.get_tensor(key)).all() for key in f.keys())
        trained = summary["provenance"]
        assert trained["stage"] == "student" and trained["degradation"] == mode and trained["steps"] >= 500
        assert "lom" not in json.dumps(trained).lower()  # never trained on the evaluation set


@pytest.mark.parametrize("mode", ["low-light"])
def test_the_bundled_model_brightens_the_example_towards_normal_light(run_cli, buu, tmp_path, mode):
    out = tmp_path / "out" / "scene.ply"
    result = run_cli("restore", EXAMPLE, "-o", out, "--mode", mode, "--json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)
    assert summary["checkpoint"]["name"] == WEIGHTS[mode].name
    assert summary["exposure_prior"]["strength"] == 0.75 and 0 < summary["exposure_prior"]["stops"] < 3
    assert summary["exposure_prior"]["key"] == "content"
    assert summary["restored_views"] == "render" and summary["uncovered"]["filled"]
    restored = load_images(out.parent / "restored").images
    inputs = load_images(EXAMPLE).images
    references = load_images([buu / "high" / f"{Path(name).stem}.JPG" for name in summary["views"]]).images
    references = torch.nn.functional.interpolate(references, size=restored.shape[-2:], mode="area")
    assert restored.mean() > 2 * inputs.mean()
    error_restored = (restored - references).abs().mean()
    error_inputs = (inputs - references).abs().mean()
    assert error_restored < 0.6 * error_inputs


def _luminance_correlation(first: torch.Tensor, second: torch.Tensor) -> float:
    """Pearson correlation of the luminance of two [3, H, W] images."""
    weights = torch.tensor([0.2126, 0.7152, 0.0722])[:, None, None]
    a, b = (first * weights).sum(0).flatten(), (second * weights).sum(0).flatten()
    return float(torch.corrcoef(torch.stack([a, b]))[0, 1])


def test_one_photo_restores_as_2d_restoration(run_cli, shared_data, buu, tmp_path):
    """One photo is a scene of one view: the bundled model restores it in 2D. A real night photo
    on which the camera head predicts a field of view of 0 once collapsed to one flat colour."""
    night = shared_data / "lowlight_single" / "003.jpg"
    out = tmp_path / "night" / "scene.ply"
    result = run_cli("restore", night, "-o", out, "--json")
    assert result.code == 0, result.err
    assert "the network predicted a camera no lens has (" in result.err
    summary = json.loads(result.out)
    photo = load_images([night]).images[0]
    restored = load_images([out.parent / "restored" / "003.png"]).images[0]
    assert restored.shape == photo.shape
    # no pile-up in a few voxels: a voxel of s pixel footprints merges about s^2 pixels of one view
    voxel_scale = RESTORE_PRESETS[DEFAULT_RESTORE_PRESET].voxel_scale
    assert summary["gaussians"]["kept"] > 0.9 * summary["gaussians"]["pixel"] / voxel_scale**2
    # the same picture, not a flat colour (it scored 0.03), and with its detail: the view is the
    # operator applied to the photo's own pixels (0.95), not a render of the Gaussians (0.85-0.9)
    assert _luminance_correlation(restored, photo) > 0.93
    assert summary["restored_views"] == "photo restoration" and summary["uncovered"] is None
    assert restored.mean() >= photo.mean()

    view = EXAMPLE / "4.jpg"
    out = tmp_path / "buu" / "scene.ply"
    result = run_cli("restore", view, "-o", out, "--json")
    assert result.code == 0, result.err
    restored = load_images([out.parent / "restored" / "4.png"]).images[0]
    photo = load_images([view]).images[0]
    reference = load_images([buu / "high" / "4.JPG"]).images[0]
    reference = torch.nn.functional.interpolate(reference[None], size=restored.shape[-2:], mode="area")[0]
    assert restored.mean() > 2 * photo.mean()
    assert (restored - reference).abs().mean() < 0.6 * (photo - reference).abs().mean()
    assert _luminance_correlation(restored, reference) > 0.8


def test_a_one_photo_restore_removes_the_noise_it_amplified(run_cli, shared_data, tmp_path):
    """LOL eval15's photos are dark and noisy, and one photo has no other views to average its
    noise: the restore measures it and removes it (closer to the normal-light photo in SSIM);
    `--no-denoise` keeps the raw restoration and says so in summary.json."""
    photo = shared_data / "lol_eval15" / "low" / "1.png"
    reference = load_images([shared_data / "lol_eval15" / "high" / "1.png"]).images[0]
    scores, summaries = {}, {}
    for option in ("--denoise", "--no-denoise"):
        out = tmp_path / option.strip("-") / "scene.ply"
        result = run_cli("restore", photo, "-o", out, "--json", option)
        assert result.code == 0, result.err
        summaries[option] = json.loads(result.out)["photo_denoising"]
        restored = load_images([out.parent / "restored" / "1.png"]).images[0]
        scores[option] = float(ssim(restored, reference))
    assert summaries["--denoise"]["filtered"] and summaries["--denoise"]["noise_level"] > MIN_NOISE_LEVEL
    assert summaries["--no-denoise"] is None
    assert scores["--denoise"] > scores["--no-denoise"] + 0.03  # 0.777 -> 0.825 on this photo


_BUU_FIVE = ["3.JPG", "6.JPG", "9.JPG", "12.JPG", "15.JPG"]


def _restore_with_registration(run_cli, buu, tmp_path, monkeypatch, unregister, portrait=(), options=()):
    """`restore --preset fast --json` of five of buu's dark photos (those named in `portrait`
    turned upright) with structure-from-motion's registration less the views
    `unregister(registration)` names; (result, photos folder, scene path)."""
    from lumos3d_cli.pipeline import scene_geometry

    real = scene_geometry.register_photos

    def registering_fewer(*args, **kwargs):
        registration = real(*args, **kwargs)
        return registration.without_views(unregister(registration))

    monkeypatch.setattr(scene_geometry, "register_photos", registering_fewer)
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in _BUU_FIVE:
        if name in portrait:
            cv2.imwrite(str(photos / name), cv2.rotate(cv2.imread(str(buu / "low" / name)), cv2.ROTATE_90_CLOCKWISE))
        else:
            (photos / name).write_bytes((buu / "low" / name).read_bytes())
    out = tmp_path / "out" / "scene.ply"
    result = run_cli("restore", photos, "-o", out, "--preset", "fast", "--json", *options)
    assert result.code == 0, result.err
    return result, photos, out


def test_photos_structure_from_motion_cannot_place_are_restored_in_2d(run_cli, buu, tmp_path, monkeypatch):
    """Structure-from-motion failing, `auto` falls back to the network's cameras, which the bundled
    models put at nearly one pose: every restored view was then a ghosted overlay of all the photos
    (8 of 33 real scenes in a QA sweep). Each view is its photo restored in 2D instead (the scene
    stays the network's); the render of the same scene at those cameras is the overlay."""
    result, photos, out = _restore_with_registration(run_cli, buu, tmp_path, monkeypatch,
                                                     lambda registration: registration.registered_indices,
                                                     options=("--video", tmp_path / "orbit.gif"))
    names = _BUU_FIVE
    assert "orbit.gif: an orbit of the network's scene, a ghosted overlay" in " ".join(result.err.split())
    said = " ".join(result.err.split())
    assert "using the network's cameras instead" in said and "restored in 2D" in said
    summary = json.loads(result.out)
    assert summary["geometry"]["source"] == "network" and summary["restored_views"] == "photo restoration"
    assert summary["refinement"] is None and summary["photo_denoising"]["views"] == names
    inputs = load_images([photos / name for name in names]).images
    restored = load_images([out.parent / "restored" / f"{name[:-4]}.png" for name in names]).images
    rendered = run_cli("render", out, "--poses", out.parent / "cameras.json", "-o", tmp_path / "renders",
                       "--fill-unobserved")
    assert rendered.code == 0, rendered.err
    renders = load_images(sorted((tmp_path / "renders").glob("*.png"))).images
    for photo, view, render in zip(inputs, restored, renders):
        assert _luminance_correlation(photo, view) > 0.95  # the photo's own picture
        assert _luminance_correlation(photo, render) < _luminance_correlation(photo, view) - 0.1  # the overlay
        assert float(view.mean()) > 2 * float(photo.mean())  # restored: the dark photo brightened


def test_views_only_the_network_places_are_restored_in_2d_and_left_out_of_the_scene(run_cli, buu, tmp_path,
                                                                                      monkeypatch):
    """Structure-from-motion registering most photos but not all: the others were placed with the
    network's cameras carried into its frame (castle-P19: 4 of 12, 156-179 degrees off), each a
    ghosted overlay, their Gaussians laid over the registered views. They are shown as their photos
    restored in 2D and kept out of the scene; the registered views are renders as before."""
    # 6.JPG upright among landscape photos: stretched into their working tensor, restored at its own size
    result, photos, out = _restore_with_registration(run_cli, buu, tmp_path, monkeypatch,
                                                     lambda registration: [1, 3], portrait={"6.JPG"})
    names = _BUU_FIVE
    said = " ".join(result.err.split())
    assert "2 view(s) not registered by structure-from-motion were placed with the network's cameras: 6.JPG, 12.JPG" in said
    assert "those 2 view(s) are shown as their photos restored in 2D and kept out of the scene" in said
    summary = json.loads(result.out)
    assert summary["geometry"]["source"] == "sfm" and summary["geometry"]["registered_views"] == 3
    assert summary["restored_views"] == "render and photo restoration"
    assert summary["photo_denoising"]["views"] == ["6.JPG", "12.JPG"]
    assert [fraction is None for fraction in summary["uncovered"]["unobserved_fraction"]] == [False, True, False, True, False]
    width, height = summary["gaussians"]["budget"]["grid"]
    assert 2 * width * height < summary["gaussians"]["pixel"] <= 3 * width * height  # the registered views alone
    inputs = load_images([photos / name for name in names]).images
    restored = load_images([out.parent / "restored" / f"{name[:-4]}.png" for name in names]).images
    for name in names:  # 6.JPG at its own 375x500, not the working tensor's 500x375
        assert cv2.imread(str(out.parent / "restored" / f"{name[:-4]}.png")).shape == cv2.imread(str(photos / name)).shape
    for index, (photo, view) in enumerate(zip(inputs, restored)):
        correlation = _luminance_correlation(photo, view)
        assert correlation > (0.95 if index in (1, 3) else 0.8), (names[index], correlation)
        assert float(view.mean()) > 2 * float(photo.mean())


def test_evaluation_keeps_every_view_in_the_scene_it_scores(buu, monkeypatch):
    """`eval` renders the views it scores: without a restore's photos (`photo_at_own_size`), views
    structure-from-motion did not register stay in the scene and are refined, as before the
    restore's 2D views (a context-protocol test frame left out scored 15.1 dB instead of 20.3)."""
    from lumos3d_cli.model.loading import load_model
    from lumos3d_cli.pipeline import scene_geometry
    from lumos3d_cli.pipeline.scene_stages import build_scene

    real = scene_geometry.register_photos
    monkeypatch.setattr(scene_geometry, "register_photos", lambda *a, **k: real(*a, **k).without_views([1, 3]))
    photos = load_images([buu / "low" / name for name in _BUU_FIVE]).images
    model = load_model(bundled_weights_path(BUNDLED_MODELS["low-light"])).eval()
    job = build_scene(photos, list(_BUU_FIVE), model, RESTORE_PRESETS["fast"], "sfm")
    assert job.geometry.source == "sfm" and int(job.registration.known.sum()) == 3
    assert job.views_in_2d == [] and job.photo_restoration is None and job.fuse_views is None
    assert job.refinement is not None


def test_a_fallback_says_once_why_structure_from_motion_was_not_used(run_cli, buu, tmp_path, monkeypatch):
    """Two of five photos registered: structure-from-motion's model is not used, and the fallback's
    warning says why; the "could not join the photos into one model" warning (for a model that is
    used) said the same line over again."""
    result, _, _ = _restore_with_registration(run_cli, buu, tmp_path, monkeypatch, lambda registration: [0, 1, 2])
    said = " ".join(result.err.split())
    assert "structure-from-motion registered 2 of 5 photos" in said and "using the network's cameras instead" in said
    assert "could not join the photos into one model" not in said
