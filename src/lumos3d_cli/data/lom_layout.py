"""The LOM layout's names (data.lom reads the scenes): a module without torch, so that `info`
can recognise a LOM scene without importing it."""

from __future__ import annotations

from pathlib import Path

REFERENCE_FOLDER = "high"  # the normal-light photos
DEGRADED_FOLDERS = {"low-light": "low", "over-exposure": "over_exp"}
TEST_CAMERAS = "transforms_test.json"


def is_lom_scene(folder: Path) -> bool:
    """`folder` holds high/, a degraded folder and transforms_test.json."""
    return (folder / REFERENCE_FOLDER).is_dir() and (folder / TEST_CAMERAS).is_file() and any(
        (folder / name).is_dir() for name in DEGRADED_FOLDERS.values()
    )


def named_root(root: Path | str) -> Path:
    """`root` with a name to give a scene: `.` or `..` (`eval .` inside a scene) resolved, so the
    scene is named after its folder, not ""."""
    root = Path(root)
    return root.resolve() if root.name in ("", "..") else root


def lom_scene_folders(root: Path) -> list[Path]:
    """The LOM scenes `root` holds, in name order: `root` itself when it is one (`named_root`),
    else its sub-folders that are; none when `root` is no folder."""
    root = named_root(root)
    if is_lom_scene(root):
        return [root]
    if not root.is_dir():
        return []
    return sorted(path for path in root.iterdir() if path.is_dir() and is_lom_scene(path))


def scene_name(name: str) -> str:
    """A scene's folder name as typed on a command line, whatever path leads to it (`buu/` as a
    shell completes it, `./buu`)."""
    return Path(name.strip()).name
