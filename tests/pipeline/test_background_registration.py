"""Structure-from-motion runs on its own thread (pipeline/scene_stages.py): on the blind tone
curve beside the network pass, on the model's restoration after it; with the result of running
it on the main thread."""

import threading
from dataclasses import replace

import pytest
import torch

from lumos3d_cli import build_model, load_images
from lumos3d_cli.errors import InputError
from lumos3d_cli.pipeline import scene_stages
from lumos3d_cli.pipeline.presets import get_restore_preset
from lumos3d_cli.pipeline.progress import SilentProgress
from lumos3d_cli.pipeline.scene_geometry import register_views
from lumos3d_cli.pipeline.scene_stages import build_scene, operator_restoration

NAMES = ["3.JPG", "4.JPG", "5.JPG", "6.JPG", "7.JPG"]


@pytest.fixture(scope="module")
def model():
    return build_model("tiny-operator", seed=0).eval()


def _tone_curve_preset():
    return replace(get_restore_preset("fast", refine_steps=0), sfm_brightening="tone curve")


def _recording_threads(monkeypatch) -> list[str]:
    """The names of the threads register_views runs on, as build_scene calls it."""
    threads = []
    real = scene_stages.register_views

    def recording(*args, **kwargs):
        threads.append(threading.current_thread().name)
        return real(*args, **kwargs)

    monkeypatch.setattr(scene_stages, "register_views", recording)
    return threads


def test_registration_on_the_tone_curve_runs_beside_the_network_with_the_same_result(buu, model, monkeypatch):
    photos = load_images([buu / "low" / name for name in NAMES]).images
    threads = _recording_threads(monkeypatch)
    built = build_scene(photos, NAMES, model, _tone_curve_preset(), geometry="sfm", max_views=3)
    assert len(threads) == 1 and threads[0].startswith("lumos3d-sfm")
    assert built.pending_registration is None
    report = built.geometry.summary()
    assert report["brightening"].startswith("auto-gamma") and report["registered_views"] == 5
    # one matching thread: the run repeats exactly, so the direct call is the oracle
    direct = register_views(photos, NAMES, "sfm", None, SilentProgress(), sfm_long_side=384)
    assert torch.equal(built.registration.cameras.extrinsics, direct.cameras.extrinsics)
    assert torch.equal(built.registration.cameras.intrinsics, direct.cameras.intrinsics)
    # the network ran once, and the photos' restoration belongs to the views it saw
    assert built.selected == [0, 2, 4]
    torch.testing.assert_close(built.restored_photos, operator_restoration(built.network, photos, built.selected))


def test_registration_on_the_restoration_runs_after_the_network_on_its_own_thread(buu, model, monkeypatch):
    photos = load_images([buu / "low" / name for name in NAMES]).images
    threads = _recording_threads(monkeypatch)
    preset = replace(get_restore_preset("fast", refine_steps=0), sfm_brightening="restoration")
    built = build_scene(photos, NAMES, model, preset, geometry="sfm", max_views=3)
    assert len(threads) == 1 and threads[0].startswith("lumos3d-sfm")
    assert built.geometry.summary()["brightening"] == "the model's restoration operator"
    brightened = scene_stages.Brightened(scene_stages.operator_restoration(built.network, photos, []), "restoration")
    direct = register_views(photos, NAMES, "sfm", None, SilentProgress(), brightened, sfm_long_side=384)
    assert torch.equal(built.registration.cameras.extrinsics, direct.cameras.extrinsics)
    torch.testing.assert_close(built.restored_photos, operator_restoration(built.network, photos, built.selected))


def test_a_view_structure_from_motion_cannot_place_joins_a_second_network_pass(buu, model):
    photos = load_images([buu / "low" / name for name in NAMES]).images
    noise = torch.rand((1, *photos.shape[1:]), generator=torch.Generator().manual_seed(0))
    photos = torch.cat([photos[:1], noise, photos[1:]])  # view 1: nothing SfM can match
    names = [NAMES[0], "noise.png", *NAMES[1:]]
    built = build_scene(photos, names, model, _tone_curve_preset(), geometry="auto", max_views=3)
    assert not bool(built.registration.known[1]) and int(built.registration.known.sum()) == 5
    # the first pass saw the even subset [0, 2, 5]; the second holds view 1, and the photos'
    # restoration was made again for the views it saw
    assert 1 in built.selected and len(built.selected) == 3
    torch.testing.assert_close(built.restored_photos, operator_restoration(built.network, photos, built.selected))
    assert "noise.png" in built.geometry.cameras.names


def test_an_error_of_the_background_registration_reaches_the_caller(model):
    noise = torch.rand((3, 3, 128, 160), generator=torch.Generator().manual_seed(1))
    with pytest.raises(InputError, match="structure-from-motion"):
        build_scene(noise, ["a.png", "b.png", "c.png"], model, _tone_curve_preset(), geometry="sfm")


def test_presets_know_only_two_brightenings():
    with pytest.raises(ValueError, match="sfm_brightening"):
        replace(get_restore_preset("fast"), sfm_brightening="curve")
