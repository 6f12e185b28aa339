"""Private temporary folders of a job's work (structure-from-motion's images and database) that
are removed however the process ends.

A folder is removed by its context manager when the work ends. Work in a background thread can
still be going on when the command ends (interrupted by Ctrl-C while structure-from-motion ran
beside the network): the `lumos3d` script then ends the process with `os._exit`, which runs no
context manager of another thread, and the folder (8-14 MB of images) stayed in /tmp for good.
`remove_work_folders` removes those still in use; the script calls it last.

A process killed outright (SIGKILL, power loss) removes nothing: its folder's name carries its
process id, host and start time (`lumos3d-sfm-<pid>-<host>-<start>.XXXX`), and the next work
folder made with the same prefix removes those whose process has ended on this host. (Two
machines sharing one /tmp under one host name cannot be told apart.)
"""

from __future__ import annotations

import contextlib
import logging
import re
import shutil
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

from lumos3d_cli.io.atomic import owner_has_ended, owner_tag

logger = logging.getLogger(__name__)

_in_use: set[Path] = set()
_lock = threading.Lock()


def _remove_killed_runs_folders(prefix: str) -> None:
    """Remove the work folders of `prefix` left by processes of this host that have ended."""
    owner = re.compile(rf"^{re.escape(prefix)}(\d+-[0-9a-f]{{8}}-\d+)\.")
    try:
        entries = list(Path(tempfile.gettempdir()).iterdir())
    except OSError:
        return
    for entry in entries:
        match = owner.match(entry.name)
        if match is not None and entry.is_dir() and not entry.is_symlink() and owner_has_ended(match[1]):
            shutil.rmtree(entry, ignore_errors=True)
            logger.info("removed %s, left behind by an earlier run that was killed", entry)


@contextlib.contextmanager
def work_folder(prefix: str) -> Iterator[Path]:
    """A new private folder in the system's temporary folder, removed when the block ends (the
    folders of killed runs with the same prefix are removed first)."""
    _remove_killed_runs_folders(prefix)
    with tempfile.TemporaryDirectory(prefix=f"{prefix}{owner_tag()}.") as name:
        folder = Path(name)
        with _lock:
            _in_use.add(folder)
        try:
            yield folder
        finally:
            with _lock:
                _in_use.discard(folder)


def remove_work_folders() -> None:
    """Remove the work folders still in use (by threads the process is about to end). Each is
    renamed first: a thread still writing into it (structure-from-motion saving its images) then
    creates nothing more there, where a file it made between the listing and the removal of the
    folder had kept the folder."""
    with _lock:
        folders = list(_in_use)
        _in_use.clear()
    for folder in folders:
        doomed = folder.with_name(f"{folder.name}.removed")
        try:
            folder.rename(doomed)
        except OSError:
            doomed = folder
        shutil.rmtree(doomed, ignore_errors=True)
