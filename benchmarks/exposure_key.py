"""Fit the exposure key predictor (`model.appearance.exposure_key`) and measure it: how far a
scene's well-exposed photo is from the fixed key (mean sRGB 0.45), and how much of that its
content predicts.

Training samples (their own exposure is the target): every third photo (at most 12) of each
normal-light scene in ../shared/data/scenes and gt_cameras, and the chosen reference of each SICE
training bracket (data/brackets.py's rule). Each source weighs half, each scene or bracket the same
within it. Scored, with features of the references themselves:
- leave-one-scene-out (and leave-one-bracket-out) on the training sources;
- the development sources, never trained on: LOM buu and shrub (each scene's normal-light views
  pooled, as a restore pools its views), LOL eval15's 15 references, the 20 held-out brackets'
  references. The ridge strength is chosen on their mean absolute error.
The restore's own numbers (the key predicted from the restored photos) are in
benchmarks/appearance_dev.py.

    .venv/bin/python benchmarks/exposure_key.py                  # table only
    .venv/bin/python benchmarks/exposure_key.py --write-weights  # also refit the bundled predictor, rewrite the model-card section
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import SHARED_DATA, markdown_table, table_section, write_section  # noqa: E402

from lumos3d_cli.data.brackets import VALIDATION_BRACKETS, pair_frames, read_bracket_index  # noqa: E402
from lumos3d_cli.data.lom import read_lom_scene  # noqa: E402
from lumos3d_cli.io.images import read_image, resize_image, to_srgb  # noqa: E402
from lumos3d_cli.model.appearance.exposure_key import BUNDLED_KEY_MODEL, KEY_FEATURE_NAMES, ExposureKeyModel  # noqa: E402
from lumos3d_cli.train.exposure_key_fit import fit_exposure_key, reference_sample  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = SHARED_DATA
MODEL_CARD = REPO / "docs" / "model-card.md"
SECTION = "exposure-key"
RIDGES = (1.0, 10.0, 100.0)
PHOTOS_PER_SCENE, PHOTO_STRIDE = 12, 3
READ_SIZE = 512  # long side the photos are read at (the scenes' own size; LOL's 600 px shrunk)


def _read(path: Path) -> torch.Tensor:
    """A photo -> [3, H, W] sRGB at most READ_SIZE on its long side."""
    pixels = to_srgb(read_image(path))
    height, width = pixels.shape[:2]
    if max(height, width) > READ_SIZE:
        scale = READ_SIZE / max(height, width)
        pixels = resize_image(pixels, round(width * scale), round(height * scale))
    return torch.from_numpy(pixels).permute(2, 0, 1).float()


def _samples(paths_by_group: dict[str, list[Path]], pooled: bool) -> list[tuple[str, torch.Tensor, float]]:
    """{group: photos} -> [(group, features, offset)]: one sample per photo, or per group pooled."""
    samples = []
    for group, paths in paths_by_group.items():
        views = [_read(path) for path in paths]
        if pooled:
            size = views[0].shape[-2:]
            views = [view for view in views if view.shape[-2:] == size]
            samples.append((group, *reference_sample(torch.stack(views))))
        else:
            samples += [(group, *reference_sample(view[None])) for view in views]
    return samples


def _training_scenes() -> dict[str, list[Path]]:
    photos = {}
    for root in (DATA / "scenes", DATA / "gt_cameras"):
        for scene in sorted(p for p in root.iterdir() if (p / "images").is_dir()):
            paths = sorted(p for p in (scene / "images").iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png"))
            photos[scene.name] = paths[::PHOTO_STRIDE][:PHOTOS_PER_SCENE]
    return photos


def _bracket_references(held_out: bool) -> dict[str, list[Path]]:
    index = read_bracket_index(DATA / "brackets")
    references = {}
    for name, frames in sorted(index.items()):
        if (name in VALIDATION_BRACKETS) != held_out:
            continue
        pairs = pair_frames(frames, "low-light", "both")
        if pairs:
            references[name] = [DATA / "brackets" / name / frames[pairs[0][1]][0]]
    return references


def _lom_references(scene: str) -> dict[str, list[Path]]:
    lom = read_lom_scene(DATA / "lom" / scene, "low-light")
    return {scene: [lom.reference[frame] for frame in lom.frames]}


def _lol_references() -> dict[str, list[Path]]:
    return {path.stem: [path] for path in sorted((DATA / "lol_eval15" / "high").glob("*.png"))}


def _stack(samples):
    groups = [group for group, _, _ in samples]
    return groups, torch.stack([features for _, features, _ in samples]), torch.tensor([offset for _, _, offset in samples], dtype=torch.float64)


def _weights(sources: list[list[str]]) -> torch.Tensor:
    """Per source, its samples' groups -> weights: each source the same, each group the same in it."""
    weights = []
    for groups in sources:
        counts = {group: groups.count(group) for group in set(groups)}
        weights += [1.0 / len(counts) / counts[group] for group in groups]
    return torch.tensor(weights, dtype=torch.float64)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write-weights", action="store_true",
                        help=f"refit the bundled predictor ({BUNDLED_KEY_MODEL.name}) and rewrite the model-card section")
    args = parser.parse_args()

    scenes = _stack(_samples(_training_scenes(), pooled=False))
    brackets = _stack(_samples(_bracket_references(held_out=False), pooled=False))
    development = {
        "LOM buu (views pooled)": _stack(_samples(_lom_references("buu"), pooled=True)),
        "LOM shrub (views pooled)": _stack(_samples(_lom_references("shrub"), pooled=True)),
        "LOL eval15 (15)": _stack(_samples(_lol_references(), pooled=False)),
        "SICE held-out (20)": _stack(_samples(_bracket_references(held_out=True), pooled=False)),
    }
    features = torch.cat([scenes[1], brackets[1]])
    offsets = torch.cat([scenes[2], brackets[2]])
    weights = _weights([scenes[0], brackets[0]])

    def cross_validated(ridge: float, source: tuple, first: int) -> float:
        """Mean over the source's groups of the absolute error with that group left out of the fit."""
        groups = source[0]
        errors = []
        for group in sorted(set(groups)):
            held = torch.tensor([first + i for i, g in enumerate(groups) if g == group])
            keep = torch.ones(len(offsets), dtype=torch.bool)
            keep[held] = False
            model = fit_exposure_key(features[keep], offsets[keep], weights[keep], ridge)
            errors.append(float((model.offset_stops(features[held]) - offsets[held]).abs().mean()))
        return sum(errors) / len(errors)

    rows, dev_means = [], {}
    fixed = [f"{float(s[2].abs().mean()):.2f}" for s in development.values()]
    rows.append(["fixed key (0.45)", f"{float(scenes[2].abs().mean()):.2f}", f"{float(brackets[2].abs().mean()):.2f}", *fixed,
                 f"{sum(float(s[2].abs().mean()) for s in development.values()) / len(development):.2f}"])
    for ridge in RIDGES:
        model = fit_exposure_key(features, offsets, weights, ridge)
        dev = [float((model.offset_stops(s[1]) - s[2]).abs().mean()) for s in development.values()]
        dev_means[ridge] = sum(dev) / len(dev)
        rows.append([f"content, ridge {ridge:g}", f"{cross_validated(ridge, scenes, 0):.2f}",
                     f"{cross_validated(ridge, brackets, len(scenes[0])):.2f}", *(f"{e:.2f}" for e in dev), f"{dev_means[ridge]:.2f}"])
    chosen = min(dev_means, key=dev_means.get)
    model = fit_exposure_key(features, offsets, weights, chosen)
    header = ["predictor", f"scenes ({len(set(scenes[0]))}, left out in turn)", f"SICE train ({len(set(brackets[0]))}, left out in turn)",
              *development, "development mean"]
    table = markdown_table(header, rows)
    coefficients = markdown_table(["feature", "mean", "deviation", "coefficient (stops per deviation)"],
                                  [[name, f"{float(m):.3f}", f"{float(s):.3f}", f"{float(c):+.3f}"] for name, m, s, c in
                                   zip(KEY_FEATURE_NAMES, model.feature_mean, model.feature_scale, model.coefficients)]
                                  + [["intercept", "", "", f"{model.intercept:+.3f}"]])
    print(table, "\n", coefficients, f"\nchosen ridge {chosen:g}", sep="\n")
    if not args.write_weights:
        return
    model.save(BUNDLED_KEY_MODEL)
    ExposureKeyModel.load(BUNDLED_KEY_MODEL)
    description = (
        "Mean absolute error, in stops, of the offset from the fixed key to each well-exposed reference's own "
        "exposure (log2 of mean linear luminance), predicted from the reference's features at the key. Training: "
        f"every {PHOTO_STRIDE}rd photo (at most {PHOTOS_PER_SCENE}) of the {len(set(scenes[0]))} normal-light scenes "
        f"(scenes/ and gt_cameras/) and the chosen references of the {len(set(brackets[0]))} SICE training brackets; "
        "each source weighs half. The development sources are never trained on; the ridge strength is chosen on "
        f"their mean (chosen: {chosen:g}). Written by `benchmarks/exposure_key.py --write-weights`, which also "
        f"writes the bundled predictor, `{BUNDLED_KEY_MODEL.name}`.")
    write_section(SECTION, table_section("#### The exposure key from the scene's content", description,
                                         table + "\n\nThe fitted predictor:\n\n" + coefficients), MODEL_CARD)
    print(f"wrote {BUNDLED_KEY_MODEL} and the {SECTION} section of {MODEL_CARD}")


if __name__ == "__main__":
    main()
