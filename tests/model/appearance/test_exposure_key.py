"""The exposure key from a scene's content (model.appearance.exposure_key), its fit
(train.exposure_key_fit) and its use by the exposure prior. Oracles: numpy's weighted least
squares for the fit, the features' invariance to the input's exposure, the fixed-key prior."""

import numpy as np
import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.colour import linear_to_srgb, srgb_to_linear
from lumos3d_cli.model.appearance.exposure_key import (
    KEY_FEATURE_NAMES,
    MAX_OFFSET_STOPS,
    ExposureKeyModel,
    bundled_key_model,
    key_features,
)
from lumos3d_cli.model.appearance.exposure_prior import (
    EXPOSURE_KEY,
    MAX_PRIOR_STOPS,
    exposure_prior_stops,
    stops_to_content_key,
    stops_to_key,
)
from lumos3d_cli.model.appearance.operator import AppearanceOperator
from lumos3d_cli.train.exposure_key_fit import fit_exposure_key, reference_sample

FEATURES = len(KEY_FEATURE_NAMES)


def _photo(seed=0, height=120, width=160) -> torch.Tensor:
    """[3, H, W] sRGB: a dark lower half, a bright textured upper half, a coloured patch."""
    generator = torch.Generator().manual_seed(seed)
    linear = 0.02 + 0.05 * torch.rand(3, height, width, generator=generator, dtype=torch.float64)
    linear[:, : height // 2] += 0.3 * torch.rand(3, height // 2, width, generator=generator, dtype=torch.float64)
    linear[0, height // 3: height // 2, width // 3: width // 2] += 0.2
    return linear_to_srgb(linear)


def _constant_model(intercept: float) -> ExposureKeyModel:
    zeros = torch.zeros(FEATURES, dtype=torch.float64)
    return ExposureKeyModel(zeros, torch.ones(FEATURES, dtype=torch.float64), zeros.clone(), intercept)


def test_features_do_not_depend_on_the_exposure_and_the_offset_does_by_exactly_its_stops():
    photo = _photo()
    darker = linear_to_srgb(srgb_to_linear(photo) * 2.0**-1.5)  # nothing clips: the same scene 1.5 stops down
    features, offset = reference_sample(photo[None])
    darker_features, darker_offset = reference_sample(darker[None])
    assert features.shape == (FEATURES,) and features.dtype == torch.float64
    torch.testing.assert_close(darker_features, features, atol=2e-4, rtol=0)
    assert darker_offset == pytest.approx(offset - 1.5, abs=1e-4)


def test_features_read_the_layout_of_the_scene():
    photo = _photo()
    features = dict(zip(KEY_FEATURE_NAMES, key_features(photo[None]).tolist()))
    flipped = dict(zip(KEY_FEATURE_NAMES, key_features(photo.flip(1)[None]).tolist()))
    assert features["top third minus bottom third"] > 0.1  # the bright half is on top
    assert flipped["top third minus bottom third"] == pytest.approx(-features["top third minus bottom third"], abs=1e-9)
    quantiles = [features[name] for name in KEY_FEATURE_NAMES[:7]]
    assert quantiles == sorted(quantiles)
    grey = key_features(torch.full((2, 3, 10, 10), 0.5, dtype=torch.float64))
    assert grey[-1] == pytest.approx(0.0, abs=1e-12)  # a grey scene has no colour


def test_features_of_tiny_and_extreme_views_are_finite():
    for views in (torch.zeros(1, 3, 1, 1), torch.ones(3, 3, 2, 5), torch.rand(64, 3, 4, 6), _photo(1, 900, 1200)[None]):
        assert torch.isfinite(key_features(views)).all()
    with pytest.raises(ValueError, match="N, 3, H, W"):
        key_features(torch.rand(3, 8, 8))


def test_the_fit_is_weighted_least_squares_on_standardised_features():
    generator = np.random.default_rng(0)
    features = generator.normal(size=(60, FEATURES)) * np.linspace(0.1, 3.0, FEATURES) + 1.0
    truth = generator.normal(size=FEATURES)
    offsets = 0.3 + features @ truth + 0.01 * generator.normal(size=60)
    weights = generator.uniform(0.2, 2.0, size=60)
    model = fit_exposure_key(torch.from_numpy(features), torch.from_numpy(offsets), torch.from_numpy(weights), ridge=0.0)
    design = np.c_[np.ones(60), features] * np.sqrt(weights)[:, None]
    oracle = np.linalg.lstsq(design, offsets * np.sqrt(weights), rcond=None)[0]
    prediction = model.offset_stops(torch.from_numpy(features)).numpy()
    expected = np.clip(np.c_[np.ones(60), features] @ oracle, -MAX_OFFSET_STOPS, MAX_OFFSET_STOPS)
    np.testing.assert_allclose(prediction, expected, atol=1e-9)
    heavy = fit_exposure_key(torch.from_numpy(features), torch.from_numpy(offsets), ridge=1e9)
    assert heavy.coefficients.abs().max() < 1e-6  # all shrunk away: the intercept is the mean offset
    assert heavy.intercept == pytest.approx(float(np.clip(offsets.mean(), -9, 9)), abs=1e-6)


def test_the_fit_refuses_bad_shapes_and_weights():
    with pytest.raises(ValueError):
        fit_exposure_key(torch.rand(5, FEATURES), torch.rand(4))
    with pytest.raises(ValueError):
        fit_exposure_key(torch.rand(5, FEATURES), torch.rand(5), torch.zeros(5))
    with pytest.raises(ValueError):
        fit_exposure_key(torch.rand(5, FEATURES), torch.rand(5), ridge=-1.0)


def test_a_model_round_trips_through_its_file_and_a_foreign_file_is_refused(tmp_path):
    model = fit_exposure_key(torch.rand(30, FEATURES, dtype=torch.float64), torch.rand(30, dtype=torch.float64), ridge=1.0)
    path = tmp_path / "key.safetensors"
    model.save(path)
    loaded = ExposureKeyModel.load(path)
    probe = torch.rand(4, FEATURES, dtype=torch.float64)
    torch.testing.assert_close(loaded.offset_stops(probe), model.offset_stops(probe), atol=0, rtol=0)
    from safetensors.torch import save_file

    save_file({"feature_mean": torch.zeros(3)}, str(tmp_path / "other.safetensors"))
    for bad in (tmp_path / "other.safetensors", tmp_path / "missing.safetensors"):
        with pytest.raises(InputError, match="exposure key model"):
            ExposureKeyModel.load(bad)
    with pytest.raises(ValueError, match="finite"):
        ExposureKeyModel(torch.full((FEATURES,), float("nan")), torch.ones(FEATURES), torch.zeros(FEATURES), 0.0)


def test_the_bundled_predictor_loads_and_stays_within_its_bound():
    model = bundled_key_model()
    for views in (_photo(2)[None], torch.zeros(1, 3, 8, 8), torch.ones(2, 3, 8, 8)):
        offset = float(model.offset_stops(key_features(views)))
        assert abs(offset) <= MAX_OFFSET_STOPS


def test_the_content_key_adds_the_predicted_offset_to_the_fixed_keys_gain():
    scenes = srgb_to_linear(torch.stack([_photo(3)[None].expand(2, -1, -1, -1), _photo(4)[None].expand(2, -1, -1, -1)]))
    scenes = scenes.float() * torch.tensor([0.5, 3.0]).view(2, 1, 1, 1, 1)
    fixed = stops_to_key(scenes)
    assert float(fixed.abs().max()) < MAX_PRIOR_STOPS - 1  # inside the bound, also with the offset
    torch.testing.assert_close(stops_to_content_key(scenes, _constant_model(0.7)), fixed + 0.7, atol=1e-5, rtol=0)
    near_bound = stops_to_content_key(scenes, _constant_model(2.0), max_stops=float(fixed.max()) + 0.5)
    assert float(near_bound.max()) == pytest.approx(float(fixed.max()) + 0.5, abs=1e-5)


def test_scenes_with_nothing_to_meter_get_no_gain_from_the_content_key():
    black, white = torch.zeros(1, 2, 3, 8, 8), torch.full((1, 2, 3, 8, 8), 4.0)
    assert stops_to_content_key(torch.cat([black, white]), _constant_model(1.5)).tolist() == [0.0, 0.0]


def test_the_prior_mixes_towards_the_content_key_and_never_darkens_a_scene_darker_than_it():
    images = linear_to_srgb(srgb_to_linear(_photo(5)[None, None].float()) * 0.25).expand(1, 3, -1, -1, -1)
    operator = AppearanceOperator.identity(1)
    fixed_key = exposure_prior_stops(operator, images, 1.0)
    for intercept in (-0.4, 0.0, 0.4):
        content = exposure_prior_stops(operator, images, 1.0, key_model=_constant_model(intercept))
        half = exposure_prior_stops(operator, images, 0.5, key_model=_constant_model(intercept))
        assert float(content) == pytest.approx(min(float(fixed_key) + intercept, MAX_PRIOR_STOPS), abs=1e-4)
        assert float(half) == pytest.approx(float(content) / 2, abs=1e-4)
        assert float(half) > 0  # the scene is darker than every key predicted: only brightened
    assert float(exposure_prior_stops(operator, images, 0.0, key_model=_constant_model(1.0))) == 0.0
    assert EXPOSURE_KEY == 0.45
