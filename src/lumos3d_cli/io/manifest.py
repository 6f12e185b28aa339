"""What lumos3d wrote in a folder, so that a later run touches only that.

`.lumos3d-manifest.json` in a folder lists every file a lumos3d command wrote there: its path
relative to the folder, size, SHA-256, the command and the output set it belongs to (e.g. one
restore's scene, or a render's frames). A later run replaces or removes a file only when the
manifest lists it and the file still holds what was written; anything else — a file the user
made, or one of ours the user has since edited — is the user's and is never touched.
"""

from __future__ import annotations

import json
import logging
import os
import stat
from dataclasses import asdict, dataclass
from pathlib import Path

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.file_digest import file_sha256

logger = logging.getLogger(__name__)

MANIFEST_NAME = ".lumos3d-manifest.json"
FORMAT = "lumos3d-manifest/1"


@dataclass(frozen=True)
class WrittenFile:
    """One file lumos3d wrote: its size in bytes, SHA-256 (hex), the command that wrote it and the
    output set it belongs to (the files that one run writes and a re-run of it replaces)."""

    bytes: int
    sha256: str
    command: str
    output_set: str


def describe_file(path: Path, command: str, output_set: str) -> WrittenFile:
    return WrittenFile(path.stat().st_size, file_sha256(path), command, output_set)


_warned: set[str] = set()  # a command reads a manifest more than once (checked early, again under the lock)


def _warn_once(message: str) -> None:
    if message not in _warned:
        _warned.add(message)
        logger.warning("%s", message)


class Manifest:
    """The manifest of `folder`: relative POSIX path -> WrittenFile."""

    def __init__(self, folder: Path, files: dict[str, WrittenFile] | None = None):
        self.folder = Path(folder)
        self.files = dict(files or {})

    @classmethod
    def read(cls, folder: Path | str) -> Manifest:
        """The folder's manifest; an absent one is empty. An unreadable one is empty too (with a
        warning): then nothing counts as ours, which refuses rather than deletes."""
        folder = Path(folder)
        path = folder / MANIFEST_NAME
        try:
            document = json.loads(path.read_text())
            if document.get("format") != FORMAT:
                raise ValueError(f"format {document.get('format')!r}")
            files = {name: WrittenFile(**entry) for name, entry in document["files"].items()}
        except FileNotFoundError:
            return cls(folder)
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as error:
            _warn_once(f"{path} cannot be read ({error}): no file in {folder} counts as written by lumos3d")
            return cls(folder)
        outside = [name for name in files if not _inside_name(name)]
        if outside:
            # lumos3d lists only files inside the folder: such a name was edited in, and is not trusted
            _warn_once(f"{path} lists {', '.join(outside)}, outside its folder: not counted as written by lumos3d")
        return cls(folder, {name: entry for name, entry in files.items() if _inside_name(name)})

    @staticmethod
    def is_manifest(path: Path) -> bool:
        """Whether `path` is a regular file holding a manifest of lumos3d's format."""
        try:
            return not path.is_symlink() and json.loads(path.read_text()).get("format") == FORMAT
        except (OSError, ValueError, AttributeError):
            return False

    def relative(self, path: Path) -> str:
        return Path(os.path.relpath(Path(path).absolute(), self.folder.absolute())).as_posix()

    def owns(self, path: Path) -> bool:
        """True when `path` (inside the folder) is a regular file the manifest lists, unchanged
        since it was written. A symbolic link is never ours: lumos3d writes none. InputError for a
        listed file that cannot be read (another user's, made unreadable): whose it is cannot be told."""
        return self.holds(self.relative(path), path)

    def holds(self, name: str, path: Path) -> bool:
        """True when the file at `path` is what the manifest lists under `name`, unchanged (`owns`,
        for a file that has since moved: an old output in a commit's trash). InputError as `owns`."""
        entry = self.files.get(name) if _inside_name(name) else None
        if entry is None:
            return False
        try:
            info = os.lstat(path)
        except FileNotFoundError:
            return False
        if not (stat.S_ISREG(info.st_mode) and info.st_size == entry.bytes):
            return False
        try:
            return file_sha256(path) == entry.sha256
        except FileNotFoundError:
            return False
        except OSError as error:
            raise InputError(f"{path}: cannot be read ({error.strerror}) to tell whether it is still what lumos3d wrote; "
                             "make it readable, or choose another output") from None

    def document(self) -> str:
        files = {name: asdict(entry) for name, entry in sorted(self.files.items())}
        return json.dumps({"format": FORMAT, "files": files}, indent=1) + "\n"


def _inside_name(name: str) -> bool:
    """A relative POSIX path that stays inside its folder (no '..', not absolute, no empty part)."""
    parts = name.split("/")
    return bool(name) and not name.startswith("/") and all(part not in ("", ".", "..") for part in parts)
