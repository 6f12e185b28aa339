"""Real exposure brackets as single-view appearance samples: a darker (or brighter) photo of a
static scene as input, the bracket's best-exposed photo of the same scene as target.

The folder (SICE, Cai et al., TIP 2018, resized to 512x512 by the Zero-DCE++ authors) holds one
sub-folder per bracket with frames 00.jpg (darkest) ... NN.jpg (brightest), and `brackets.json`
mapping each bracket to its frames' files and mean sRGB brightness.

Pairing rule (per bracket):
- target: the frame whose mean brightness is closest to WELL_EXPOSED_MEAN (0.45, the level the
  auto-gamma baseline aims for); a bracket whose closest frame lies outside TARGET_MEAN_RANGE
  has no well-exposed frame and gives no pairs;
- low-light inputs: frames with mean <= target mean / 2 (at least half as bright);
- over-exposure inputs: frames whose headroom (1 - mean) <= target headroom / 2 (at least half
  the distance to white gone).
Frames in between are too close to the target to teach restoration. They, and the target itself
(paired with itself), are the `well-exposed` inputs: a head also trained on them learns to leave
a photo that is already well exposed nearly as it is, instead of brightening (or darkening)
every photo the same way. `inputs` picks "restore" (the rule above), "well-exposed" or "both".

VALIDATION_BRACKETS, 20 brackets fixed once (evenly spaced over the brackets that have a target
and both kinds of input), are held out for validation and model selection.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from lumos3d_cli.data.augment import crop_and_resize, crop_box
from lumos3d_cli.data.modes import MODES
from lumos3d_cli.data.photo_reading import read_training_photo
from lumos3d_cli.errors import InputError

logger = logging.getLogger(__name__)

SPLITS = ("train", "validation", "all")
INPUT_KINDS = ("restore", "well-exposed", "both")
WELL_EXPOSED_MEAN = 0.45
TARGET_MEAN_RANGE = (0.3, 0.6)
BRIGHTNESS_FACTOR = 2.0
VALIDATION_BRACKETS = (
    "000", "012", "023", "033", "041", "052", "064", "072", "081", "097",
    "107", "121", "130", "141", "149", "159", "169", "188", "197", "211",
)  # fmt: skip


@dataclass(frozen=True)
class BracketPair:
    """One training pair: input and target files of one bracket, their mean sRGB brightness,
    and the mode the input shows ("low-light" or "over-exposure")."""

    bracket: str
    input_path: Path
    target_path: Path
    input_mean: float
    target_mean: float
    mode: str


def read_bracket_index(root: Path | str) -> dict[str, list[tuple[str, float]]]:
    """root/brackets.json -> {bracket: [(file name, mean brightness), ...] darkest first}."""
    index_path = Path(root) / "brackets.json"
    if not index_path.is_file():
        raise InputError(f"{index_path} not found; point to the brackets folder (it holds brackets.json and one folder per bracket)")
    try:
        raw = json.loads(index_path.read_text())
        return {name: [(str(f["file"]), float(f["mean"])) for f in frames] for name, frames in raw.items()}
    except (ValueError, KeyError, TypeError) as error:
        raise InputError(f"{index_path}: expected {{bracket: [{{file, mean}}, ...]}}, could not read it ({error})") from None


def pair_frames(frames: list[tuple[str, float]], mode: str, inputs: str = "restore") -> list[tuple[int, int]]:
    """Frames [(file, mean)] of one bracket -> [(input index, target index)] by the module's rule,
    for the input kind `inputs` (INPUT_KINDS)."""
    if mode not in MODES:
        raise InputError(f"unknown mode '{mode}'; choose one of: {', '.join(MODES)}")
    if inputs not in INPUT_KINDS:
        raise InputError(f"unknown bracket inputs '{inputs}'; choose one of: {', '.join(INPUT_KINDS)}")
    if not frames:
        return []
    means = np.array([mean for _, mean in frames])
    target = int(np.argmin(np.abs(means - WELL_EXPOSED_MEAN)))
    low, high = TARGET_MEAN_RANGE
    if not low <= means[target] <= high:
        return []
    # distance from the well-exposed end: brightness for low light, headroom for over-exposure
    level = means if mode == "low-light" else 1 - means
    restore = level <= level[target] / BRIGHTNESS_FACTOR
    well_exposed = (level <= level[target]) & ~restore
    chosen = {"restore": restore, "well-exposed": well_exposed, "both": restore | well_exposed}[inputs]
    return [(int(i), target) for i in np.flatnonzero(chosen)]


def bracket_pairs(root: Path | str, mode: str, split: str = "train", inputs: str = "restore") -> list[BracketPair]:
    """All pairs of one mode and input kind (pair_frames) in a split: "train" (every bracket but
    the validation ones), "validation" (VALIDATION_BRACKETS) or "all". Sorted by bracket, then
    input frame."""
    if split not in SPLITS:
        raise InputError(f"unknown split '{split}'; choose one of: {', '.join(SPLITS)}")
    root = Path(root)
    index = read_bracket_index(root)
    held_out = set(VALIDATION_BRACKETS)
    pairs = []
    for name in sorted(index):
        if (split == "train" and name in held_out) or (split == "validation" and name not in held_out):
            continue
        frames = index[name]
        for source, target in pair_frames(frames, mode, inputs):
            pairs.append(BracketPair(
                name, root / name / frames[source][0], root / name / frames[target][0], frames[source][1], frames[target][1], mode,
            ))  # fmt: skip
    missing = sorted(set(VALIDATION_BRACKETS) - set(index)) if split != "train" else []
    if missing:
        raise InputError(f"{root / 'brackets.json'} lacks validation bracket(s) {', '.join(missing)}; is this the SICE brackets folder?")
    return pairs


def read_srgb(path: Path) -> torch.Tensor:
    """One photo -> [3, H, W] float32 sRGB in [0, 1]; InputError naming a missing file."""
    if not path.is_file():
        raise InputError(f"{path} is listed in brackets.json but missing; restore the brackets folder")
    return torch.from_numpy(read_training_photo(path)).permute(2, 0, 1).contiguous()


class BracketDataset(Dataset):
    """Samples of one mode and split: images [1, 3, H, W] (the input, one view), targets
    [1, 3, H, W], bracket name and mode. The same random crop (covering `crop_scale` of the
    largest box of the output's aspect ratio) and mirror for input and target, resized to
    `size` (width, height). crop_scale (1, 1) and flip False give the whole frame, as
    validation wants. `inputs`: the kind of input frames (pair_frames).

    Deterministic: sample i of epoch e depends only on (seed, e, i).
    """

    def __init__(
        self,
        root: Path | str,
        mode: str,
        split: str,
        size: tuple[int, int],
        crop_scale: tuple[float, float] = (0.6, 1.0),
        flip: bool = True,
        seed: int = 0,
        inputs: str = "restore",
    ):
        self.pairs = bracket_pairs(root, mode, split, inputs)
        if not self.pairs:
            raise InputError(f"{root}: no {mode} pairs with {inputs} inputs in the {split} split")
        logger.info("%d %s bracket pairs (%s inputs, %s split) from %s", len(self.pairs), mode, inputs, split, root)
        self.width, self.height = size
        self.crop_scale = crop_scale
        self.flip = flip
        self.seed = seed
        self.epoch = 0

    def __len__(self) -> int:
        return len(self.pairs)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __getitem__(self, index: int) -> dict:
        rng = np.random.default_rng([self.seed, self.epoch, index])
        pair = self.pairs[index]
        source, target = read_srgb(pair.input_path), read_srgb(pair.target_path)
        if source.shape != target.shape:
            raise InputError(f"{pair.input_path} and {pair.target_path} differ in size; bracket frames must align")
        frames = torch.stack((source, target))  # [2, 3, H, W]
        height, width = frames.shape[-2:]
        box = crop_box(width, height, self.width, self.height, rng.uniform(*self.crop_scale), rng)
        frames, _ = crop_and_resize(frames, None, box, self.width, self.height)
        if self.flip and rng.random() < 0.5:
            frames = frames.flip(-1)
        return {"images": frames[:1], "targets": frames[1:], "bracket": pair.bracket, "mode": pair.mode}
