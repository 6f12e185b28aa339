"""Helpers of the data-safety tests: real photos to restore, a quick restore's command line, and
snapshots of folders to compare byte by byte."""

import shutil
from pathlib import Path

from lumos3d_cli.io.manifest import MANIFEST_NAME

PHOTOS = ["1.JPG", "2.JPG", "3.JPG", "4.JPG", "5.JPG", "6.JPG"]


def copy_photos(buu: Path, folder: Path, names=PHOTOS) -> Path:
    folder.mkdir(parents=True)
    for name in names:
        shutil.copy(buu / "low" / name, folder / name)
    return folder


def restore_args(photos, output, weights, *extra):
    """A quick restore: network cameras, no refinement."""
    return ("restore", photos, "-o", output, "--checkpoint", weights, "--geometry", "network", "--preset", "fast",
            "--refine-steps", 0, *extra)


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under `folder` (hidden ones included) by relative path -> its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(Path(folder).rglob("*")) if p.is_file()}


def listing(folder: Path) -> list[str]:
    """The names in `folder`, sorted, but for lumos3d's manifest of what it wrote there."""
    return sorted(p.name for p in Path(folder).iterdir() if p.name != MANIFEST_NAME)
