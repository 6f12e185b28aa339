"""Write outputs so that they appear whole or not at all: write under a temporary name, then rename.

Temporary names are hidden and carry the writing process's id and a tag of its host,
`.NAME.<pid>-<host>.XXXXXXXX.tmp[.suffix]`. A run that is killed outright (SIGKILL, power loss)
cannot clean up after itself; the next run writing into the same folder recognises such
leftovers — their process no longer exists on this host — and removes them, while the
temporaries of a run still going on (same host, live process) or of another host are left alone.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import socket
import tempfile
import zlib
from collections.abc import Iterator
from pathlib import Path

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.output_paths import blocking_file

logger = logging.getLogger(__name__)

_HOST = f"{zlib.crc32(socket.gethostname().encode()):08x}"
# What follows ".NAME." in a temporary name: "<pid>-<host>.<random>.tmp", then an optional suffix.
_OWNER = re.compile(r"\.(?P<pid>\d+)-(?P<host>[0-9a-f]{8})\.[a-z0-9_]+\.tmp(\.[^.]*)?$")
# Folders already cleaned by this process: listing a folder again for every file written into it
# would cost O(files²) for a render of thousands of frames.
_cleaned: set[Path] = set()


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _prefix(name: str) -> str:
    """The start of this process's temporary names for an output called `name`."""
    return f".{name}.{os.getpid()}-{_HOST}."


def _process_exists(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def _is_leftover(name: str) -> bool:
    """True for a temporary of ours whose writer, a process on this host, has ended."""
    match = _OWNER.search(name)
    return (
        name.startswith(".") and match is not None and match["host"] == _HOST
        and not _process_exists(int(match["pid"]))
    )


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def remove_leftovers(folder: Path | str) -> list[Path]:
    """Remove the temporaries in `folder` left by killed runs on this host (once per folder and
    process); returns what was removed."""
    folder = Path(folder).absolute()
    if folder in _cleaned:
        return []
    try:
        entries = list(folder.iterdir())
    except (FileNotFoundError, NotADirectoryError):
        return []
    _cleaned.add(folder)
    removed = [entry for entry in entries if _is_leftover(entry.name)]
    for entry in removed:
        _remove(entry)
        logger.info("removed %s, left behind by an earlier run that was killed", entry)
    return removed


def _make_folder(folder: Path) -> list[Path]:
    """mkdir -p `folder`; returns the folders it created, outermost first (to undo on failure)."""
    missing = [parent for parent in [folder, *folder.parents] if not parent.exists()]
    blocker = blocking_file(folder / "output")
    if blocker is not None:  # commands check their outputs first (check_output_path); this is the last guard
        raise InputError(f"{folder}: cannot be created because {blocker} is a file, not a folder; choose another path")
    folder.mkdir(parents=True, exist_ok=True)
    return missing[::-1]


def _remove_created(created: list[Path]) -> None:
    """Remove folders `_make_folder` created, innermost first, where they are still empty."""
    for folder in reversed(created):
        with contextlib.suppress(OSError):
            folder.rmdir()


@contextlib.contextmanager
def atomic_path(final: Path | str) -> Iterator[Path]:
    """Yield a temporary path beside `final` (same suffix); rename it onto `final` when the block
    succeeds; when the block raises (an interruption included) delete it and any folder created
    for it."""
    final = Path(final)
    created = _make_folder(final.parent)
    remove_leftovers(final.parent)
    handle, name = tempfile.mkstemp(prefix=_prefix(final.stem), suffix=f".tmp{final.suffix}", dir=final.parent)
    os.close(handle)
    temporary = Path(name)
    try:
        yield temporary
        # mkstemp (and writers that replace the file, like safetensors) create 0600; outputs follow the umask
        os.chmod(temporary, 0o666 & ~_current_umask())
        os.replace(temporary, final)
    except BaseException:
        temporary.unlink(missing_ok=True)
        _remove_created(created)
        raise


def _check_kinds(staging: Path, final: Path, replace_folders: bool) -> None:
    """Refuse, before anything moves, an output whose name is taken by the other kind (a file
    where a folder goes, or a folder where a file goes): a half-moved output set would remain."""
    items = staging.iterdir() if replace_folders else staging.rglob("*")
    for item in items:
        target = final / item.relative_to(staging)
        if target.exists() and item.is_dir() != target.is_dir():
            found, needed = ("a folder", "a file") if target.is_dir() else ("a file", "a folder")
            raise InputError(f"{target}: is {found} but the output written there is {needed}; move it away or choose another output")


def _move_into(staging: Path, final: Path, replace_folders: bool) -> None:
    """Move the staged outputs into `final`. An existing folder being replaced is renamed into the
    staging folder first (deleted with it), so the new one takes its place in one rename."""
    items = sorted(staging.iterdir())
    replaced = staging / ".replaced"
    for item in items:
        target = final / item.name
        if item.is_dir() and replace_folders:
            if target.exists() or target.is_symlink():
                replaced.mkdir(exist_ok=True)
                os.replace(target, replaced / item.name)
            os.replace(item, target)
        elif item.is_dir():
            for inner in sorted(item.rglob("*")):
                destination = final / inner.relative_to(staging)
                if inner.is_dir():
                    destination.mkdir(parents=True, exist_ok=True)
                else:
                    destination.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(inner, destination)
        else:
            os.replace(item, target)


@contextlib.contextmanager
def atomic_directory(final: Path | str, replace_folders: bool = False) -> Iterator[Path]:
    """Yield an empty staging folder (hidden, inside `final`); when the block succeeds its contents
    move into `final`, which is created if needed.

    Files replace files of the same name; everything else already in `final` stays. Sub-folders
    merge file by file, or with `replace_folders` replace the folder of the same name whole, so
    that e.g. `restored/` holds exactly the views this run wrote and none of an earlier run's.
    `final` itself is never replaced or emptied: it may be the user's home folder.
    When the block raises (an interruption included) the staging folder is removed and `final`
    is left as it was (removed if this call created it).
    """
    final = Path(final)
    created = _make_folder(final)
    remove_leftovers(final)
    prefix = _prefix("staging")
    earlier = {item.name for item in final.iterdir() if item.name.startswith(prefix)}
    staging, succeeded = None, False
    try:
        staging = Path(tempfile.mkdtemp(prefix=prefix, suffix=".tmp", dir=final))
        yield staging
        _check_kinds(staging, final, replace_folders)
        _move_into(staging, final, replace_folders)
        succeeded = True
    finally:
        # A signal can land after mkdtemp made the folder but before `staging` names it: then the
        # folder to remove is the one of this process's staging folders that was not there before.
        made = [staging] if staging is not None else [
            item for item in final.iterdir() if item.name.startswith(prefix) and item.name not in earlier]
        for folder in made:
            shutil.rmtree(folder, ignore_errors=True)
        if not succeeded:
            _remove_created(created)


def write_bytes_atomic(final: Path | str, data: bytes) -> None:
    """Write `data` to `final` atomically."""
    with atomic_path(final) as temporary:
        temporary.write_bytes(data)
