"""The LOM layout (Aleth-NeRF authors): `<scene>/{high,low,over_exp}/` photos of the same views
and `transforms_{train,val,test}.json`. For evaluation only; never for training.

A view is its file stem, matched case-insensitively between the folders and the transforms files
(LOM's shrub has `low/1.JPG` beside `over_exp/1.jpg`); its id is the spelling in `high/`."""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from lumos3d_cli.data.lom_layout import DEGRADED_FOLDERS, lom_scene_folders, named_root, scene_name
from lumos3d_cli.errors import InputError, listed
from lumos3d_cli.io.image_files import IMAGE_SUFFIXES, natural_sort_key
from lumos3d_cli.io.input_folders import require_folder
from lumos3d_cli.io.transforms_json import read_transforms_json

logger = logging.getLogger(__name__)

CAMERA_FILES = ("transforms_train.json", "transforms_val.json", "transforms_test.json")


@dataclass(frozen=True)
class LomScene:
    """frames: view ids (file stems) in natural order; test: the ids of transforms_test.json;
    degraded[id] and reference[id]: the photo under the evaluated condition and under normal light."""

    name: str
    root: Path
    mode: str
    frames: list[str]
    test: list[str]
    degraded: dict[str, Path]
    reference: dict[str, Path]


def _by_stem(folder: Path) -> dict[str, Path]:
    """The photos of `folder` by case-folded stem; InputError when two photos share one."""
    photos: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if not (path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES and not path.name.startswith(".")):
            continue
        key = path.stem.casefold()
        if key in photos:
            raise InputError(f"{folder}: {photos[key].name} and {path.name} are the same view; keep one of them")
        photos[key] = path
    return photos


def read_lom_scene(folder: Path, mode: str) -> LomScene:
    """One scene; InputError for a missing folder, test frame or degraded photo."""
    if mode not in DEGRADED_FOLDERS:
        raise InputError(f"{mode!r}: use one of {', '.join(DEGRADED_FOLDERS)}", parameter="mode")
    degraded_folder = folder / DEGRADED_FOLDERS[mode]
    if not degraded_folder.is_dir():
        raise InputError(f"{folder}: no {DEGRADED_FOLDERS[mode]}/ folder for mode {mode}")
    reference = _by_stem(folder / "high")
    degraded = _by_stem(degraded_folder)
    try:
        frames = json.loads((folder / "transforms_test.json").read_text())["frames"]
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as error:
        raise InputError(f"{folder / 'transforms_test.json'}: cannot read its frames ({error})") from error
    if not isinstance(frames, list) or not all(isinstance(frame, dict) for frame in frames):
        raise InputError(f"{folder / 'transforms_test.json'}: \"frames\" must be a list of objects, each with a "
                         "\"file_path\"")
    try:
        test_keys = [Path(frame["file_path"]).stem for frame in frames]
    except KeyError as error:
        raise InputError(f"{folder / 'transforms_test.json'}: a frame without a file_path ({error})") from error
    except TypeError:
        raise InputError(f"{folder / 'transforms_test.json'}: a frame's file_path is not a path (a string)") from None
    if not test_keys:
        raise InputError(f"{folder / 'transforms_test.json'}: lists no test frames; eval scores the frames it lists")
    folded = [key.casefold() for key in test_keys]
    unique = list(dict.fromkeys(folded))
    if len(unique) < len(test_keys):  # scored twice, a frame would weigh twice in the scene's mean
        test_keys = [test_keys[folded.index(key)] for key in unique]  # each frame as first spelt
        twice = [key for key in test_keys if folded.count(key.casefold()) > 1]
        logger.warning("%s: lists %s more than once; each test frame is scored once",
                       folder / "transforms_test.json", listed(twice, 4))
    for frame in test_keys:
        if frame.casefold() not in reference:
            raise InputError(f"{folder}: test frame {frame!r} has no normal-light photo in high/")
        if frame.casefold() not in degraded:
            raise InputError(f"{folder}: test frame {frame!r} has no photo in {DEGRADED_FOLDERS[mode]}/")
    ids = {key: reference[key].stem for key in reference}  # case-folded stem -> the view's id
    shared = sorted(set(reference) & set(degraded), key=lambda key: natural_sort_key(ids[key]))
    for lacking, present, name in ((degraded, reference, DEGRADED_FOLDERS[mode]), (reference, degraded, "high")):
        unmatched = sorted((f"{present[key].parent.name}/{present[key].name}" for key in set(present) - set(lacking)),
                           key=natural_sort_key)
        if unmatched:
            logger.warning("%s: %s %s no photo in %s/; the scene is evaluated without %s", folder, listed(unmatched, 4),
                           "has" if len(unmatched) == 1 else "have", name, "it" if len(unmatched) == 1 else "them")
    return LomScene(folder.name, folder, mode, [ids[k] for k in shared], [ids[f.casefold()] for f in test_keys],
                    {ids[k]: degraded[k] for k in shared}, {ids[k]: reference[k] for k in shared})


def _missing_parts(folder: Path) -> str:
    """What `folder` lacks of a LOM scene, in words (e.g. "transforms_test.json")."""
    parts = [] if (folder / "high").is_dir() else ["high/"]
    if not (folder / "transforms_test.json").is_file():
        parts.append("transforms_test.json")
    if not any((folder / f).is_dir() for f in DEGRADED_FOLDERS.values()):
        parts.append("low/ or over_exp/")
    return " and ".join(str(folder / part) for part in parts)


def find_lom_scenes(root: Path | str, mode: str, names: str | Sequence[str] | None = None) -> list[LomScene]:
    """Scenes under `root` (or `root` itself when it is one): all (`names` None), or those named
    (one name, or several)."""
    root = named_root(root)
    require_folder(root, "that holds the LOM scenes, or one scene")
    names = [names] if isinstance(names, str) else names
    if names is not None and len(names) == 0:
        raise InputError("[]: name at least one scene, or none at all for every scene found", parameter="scenes")
    names = None if names is None else list(dict.fromkeys(scene_name(name) for name in names))
    folders = lom_scene_folders(root)
    if names:
        available = {p.name for p in folders}
        missing = [n for n in names if n not in available]
        for name in missing:
            if (root / name).is_dir():
                raise InputError(f"{root / name}: not a LOM-layout scene: {_missing_parts(root / name)} is missing")
        if missing:
            raise InputError(f"{root}: no LOM scene(s) {', '.join(missing)} (found: {', '.join(sorted(available)) or 'none'})")
        folders = [p for p in folders if p.name in names]
    if not folders:
        detail = f": {_missing_parts(root)} is missing" if any((root / f).is_dir() for f in ("high", *DEGRADED_FOLDERS.values())) else ""
        raise InputError(f"{root}: no LOM-layout scenes (high/ + low/ or over_exp/ + transforms_test.json){detail}")
    return [read_lom_scene(folder, mode) for folder in folders]


def lom_reference_extrinsics(scene: LomScene) -> dict[str, torch.Tensor]:
    """The dataset's cameras of the scene's frames: id -> world->camera extrinsics [3, 4]
    (float64, OpenCV axes), from whichever transforms_{train,val,test}.json exist (their file
    stems matched to the frames' ids case-insensitively)."""
    ids = {frame.casefold(): frame for frame in scene.frames}
    extrinsics = {}
    for name in CAMERA_FILES:
        path = scene.root / name
        if path.is_file():
            cameras = read_transforms_json(path, warn_on_distortion=False)
            for index, file_path in enumerate(cameras.names):
                stem = Path(file_path).stem
                extrinsics[ids.get(stem.casefold(), stem)] = cameras.extrinsics[index]
    return extrinsics
