"""Private temporary folders of a job's work (structure-from-motion's images and database) that
are removed however the process ends.

A folder is removed by its context manager when the work ends. Work in a background thread can
still be going on when the command ends (interrupted by Ctrl-C while structure-from-motion ran
beside the network): the `lumos3d` script then ends the process with `os._exit`, which runs no
context manager of another thread, and the folder (8-14 MB of images) stayed in /tmp for good.
`remove_work_folders` removes those still in use; the script calls it last.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

_in_use: set[Path] = set()
_lock = threading.Lock()


@contextlib.contextmanager
def work_folder(prefix: str) -> Iterator[Path]:
    """A new private folder in the system's temporary folder, removed when the block ends."""
    with tempfile.TemporaryDirectory(prefix=prefix) as name:
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
