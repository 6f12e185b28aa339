"""Check an output path before any work is done, so that a run never computes for minutes and
then fails to write: its folder must be creatable (no regular file on the way) and writable."""

from __future__ import annotations

import errno
import os
from pathlib import Path

from lumos3d_cli.errors import InputError


def blocking_file(path: Path) -> Path | None:
    """The nearest existing ancestor of `path` when it is not a folder (so `path` cannot be
    created), else None."""
    for ancestor in Path(path).absolute().parents:
        if ancestor.exists():
            return None if ancestor.is_dir() else ancestor
    return None


def dangling_link(path: Path) -> Path | None:
    """The first of `path` and its ancestors that is a symbolic link to nothing, else None
    (writing through it would fail, or replace the link, only after all the work)."""
    for candidate in [path, *path.absolute().parents]:
        if candidate.is_symlink() and not candidate.exists():
            return candidate
    return None


def _leads_round(link: Path) -> bool:
    """Whether following `link` ends in a loop of links (a chain that ends at nothing does not)."""
    try:
        os.stat(link)
    except OSError as error:
        return error.errno == errno.ELOOP
    return False


def check_output_path(path: Path | str | None, parameter: str | None, folder: bool = False) -> None:
    """InputError (naming `parameter` and `path`) unless `path` can be written: as a folder when
    `folder`, else as a file. None (an optional output not asked for) passes."""
    if path is None:
        return
    path = Path(path)
    link = dangling_link(path)
    if link is not None:
        target = os.readlink(link)
        if _leads_round(link):  # not a link to nothing: links that lead back to themselves
            raise InputError(f"{path}: {link} is a link to {target}, whose links lead round in a loop; fix the links or "
                             "choose another path", parameter=parameter)
        raise InputError(f"{path}: {link} is a link to {target}, which does not exist; create it or choose "
                         "another path", parameter=parameter)
    blocker = blocking_file(path)
    if blocker is not None:
        raise InputError(f"{path}: cannot be created because {blocker} is a file, not a folder; choose another path",
                         parameter=parameter)
    if path.exists() and path.is_dir() != folder:
        found, needed = ("a folder", "a file") if path.is_dir() else ("a file", "a folder")
        raise InputError(f"{path}: is {found}; give {needed} here", parameter=parameter)
    existing = next(p for p in [path, *path.absolute().parents] if p.exists())
    writable_folder = existing if existing.is_dir() else existing.parent
    if not os.access(writable_folder, os.W_OK | os.X_OK):
        raise InputError(f"{path}: no permission to write in {writable_folder}; choose another path", parameter=parameter)


def require_new_file(path: Path, overwrite: bool) -> None:
    """For the library's file writers (`write_ply`, `write_splat`, `save_checkpoint`): InputError
    when `path` exists (a file, a link or a folder) unless `overwrite`; they replace a file only
    when asked, as the commands replace only what lumos3d wrote (io/output_set.py)."""
    if path.is_dir() and not path.is_symlink():
        raise InputError(f"{path}: is a folder; give a file name")
    if not overwrite and (path.exists() or path.is_symlink()):
        raise InputError(f"{path}: exists; lumos3d does not replace it unless asked (overwrite=True), or choose another name")
