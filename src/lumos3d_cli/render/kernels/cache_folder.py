"""Where numba keeps the compiled kernels (`cache=True`: a restore compiles them once, about 30 s
on 2 cores, then loads them in a fraction of a second).

numba writes beside the source (`kernels/__pycache__`) or, where that is read-only (an installed
package), in the user's cache (`$XDG_CACHE_HOME/numba` or `~/.cache/numba`); where neither can be
written (a read-only install run by a service account without a home) it stops every render with
"cannot cache function ...: no locator available". Then the kernels are cached in the temporary
folder instead: in a folder of this user's alone (numba loads pickles from it, so a folder that
another account made or can write is never used; a fresh private one is made instead).
"""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path


def writable(folder: Path) -> bool:
    """Whether files can be made in `folder`, or where it does not exist yet, in the nearest
    folder above it that does (numba creates the rest)."""
    while not folder.exists():
        if folder.parent == folder:
            return False
        folder = folder.parent
    return folder.is_dir() and os.access(folder, os.W_OK | os.X_OK)


def fallback_cache_folder(kernels: Path, environ: Mapping[str, str],
                          can_write: Callable[[Path], bool] = writable) -> Path | None:
    """None where numba's own choice works (NUMBA_CACHE_DIR is set, or `kernels`/__pycache__ or
    the user's cache can be written); else a folder of the temporary directory for this user."""
    if environ.get("NUMBA_CACHE_DIR"):
        return None
    if can_write(kernels / "__pycache__"):
        return None
    user_cache = Path(environ.get("XDG_CACHE_HOME") or Path(environ.get("HOME") or Path.home()) / ".cache")
    if can_write(user_cache / "numba"):
        return None
    return private_temporary_folder()


def private_temporary_folder() -> Path:
    """`lumos3d-numba-<uid>` in the temporary directory, made with mode 0700, where it is a real
    folder owned by this user that no one else can enter; else a fresh private folder."""
    uid = getattr(os, "getuid", lambda: None)()
    if uid is not None:
        folder = Path(tempfile.gettempdir()) / f"lumos3d-numba-{uid}"
        try:
            folder.mkdir(mode=0o700)
        except FileExistsError:
            pass
        except OSError:
            return Path(tempfile.mkdtemp(prefix="lumos3d-numba-"))
        status = folder.lstat()
        if stat.S_ISDIR(status.st_mode) and status.st_uid == uid and not status.st_mode & 0o077:
            return folder
    return Path(tempfile.mkdtemp(prefix="lumos3d-numba-"))
