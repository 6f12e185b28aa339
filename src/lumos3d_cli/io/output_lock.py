"""One lumos3d run at a time per output folder.

A run that writes into a folder holds `.lumos3d.lock` there (an exclusive `flock`, which the
kernel releases when the process ends however it ends, so a killed run never blocks the next).
A second run into the same folder is refused at once, naming the run that holds it, instead of
interleaving its files with the first's. The lock is re-entrant within a process: the CLI takes
it before the computation and the writing takes it again.
"""

from __future__ import annotations

import contextlib
import datetime
import fcntl
import json
import logging
import os
import socket
import stat
from collections.abc import Iterator
from pathlib import Path

from lumos3d_cli.errors import InputError

LOCK_NAME = ".lumos3d.lock"

logger = logging.getLogger(__name__)

# folder (absolute) -> [descriptor, depth] of the locks this process holds
_held: dict[Path, list[int]] = {}


def _describe_holder(descriptor: int) -> str:
    """What the holding run wrote into the lock file: command, process id, host, start time."""
    try:
        holder = json.loads(os.pread(descriptor, 4096, 0).decode())
        return f"`lumos3d {holder['command']}`, process {holder['pid']} on {holder['host']}, started {holder['started']}"
    except (OSError, ValueError, KeyError, TypeError):
        return "another lumos3d process"


def _is_our_record(descriptor: int) -> bool:
    """Whether the lock file holds the record of a lumos3d run (a killed run's is left behind), or
    nothing: a run that made it and was killed before writing its record, or one that made it a
    moment ago and has not taken it yet (the lock decides between the two runs). Anything else is
    a file of the user's that only shares the name."""
    content = os.pread(descriptor, 4096, 0)
    if not content:
        return True
    try:
        return {"command", "pid", "host", "started"} <= set(json.loads(content.decode()))
    except (ValueError, TypeError, UnicodeDecodeError):
        return False


def holds_a_lock_record(path: Path) -> bool:
    """Whether the file at `path` is a lumos3d lock file (`_is_our_record`): one a killed run left
    where the lock is not held."""
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:
        return False
    try:
        return stat.S_ISREG(os.fstat(descriptor).st_mode) and _is_our_record(descriptor)
    finally:
        os.close(descriptor)


def _not_ours(path: Path) -> InputError:
    return InputError(f"{path}: is not lumos3d's lock file but takes its name; move it away or choose another output")


def _open_lock_file(folder: Path, path: Path) -> int | None:
    """A descriptor of the lock file, made by this call where there is none (O_EXCL: whether this
    run made it is known, not guessed from a look before: another run could remove its own in
    between); None when the file went between the two opens (try again)."""
    flags = os.O_RDWR | os.O_NOFOLLOW  # never through a link, never onto a folder or device
    try:
        return os.open(path, flags | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        pass
    except OSError as error:
        if not os.path.lexists(path):  # nothing there: the folder takes no file (/sys, a read-only mount)
            raise InputError(f"{folder}: no file can be written there ({error.strerror}); choose another "
                             "output") from None
        raise _not_ours(path) from error
    try:
        return os.open(path, flags)
    except FileNotFoundError:  # its run removed it meanwhile
        return None
    except OSError as error:
        raise _not_ours(path) from error


def _acquire(folder: Path, command: str) -> int:
    path = folder / LOCK_NAME
    while True:
        descriptor = _open_lock_file(folder, path)
        if descriptor is None:
            continue
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            os.close(descriptor)
            raise _not_ours(path)
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _describe_holder(descriptor)
            os.close(descriptor)
            raise InputError(f"{folder}: {holder} is writing its outputs here; wait for it to end or choose another "
                             "output folder") from None
        try:
            same_file = os.fstat(descriptor).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same_file = False
        if not same_file:
            # The holder removed the file between our open and our lock: we hold a lock on a file
            # that no longer has a name, which excludes no one. Try again on the current file.
            os.close(descriptor)
            continue
        if not _is_our_record(descriptor):
            os.close(descriptor)
            raise _not_ours(path)
        break
    started = datetime.datetime.now().isoformat(timespec="seconds")
    record = json.dumps({"command": command, "pid": os.getpid(), "host": socket.gethostname(), "started": started})
    os.ftruncate(descriptor, 0)
    os.pwrite(descriptor, record.encode(), 0)
    return descriptor


def lock_holder(folder: Path | str) -> str | None:
    """The run that holds `folder`'s lock, described (command, process id, host, start time), when
    another one does; None when none does or this process holds it. Creates nothing."""
    folder = Path(folder).resolve()
    if folder in _held:
        return None
    try:
        descriptor = os.open(folder / LOCK_NAME, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:  # no lock file (or one that is not ours: `folder_lock` names it)
        return None
    try:
        if stat.S_ISREG(os.fstat(descriptor).st_mode):
            try:
                fcntl.flock(descriptor, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:
                return _describe_holder(descriptor)
        return None
    finally:
        os.close(descriptor)  # closing releases a shared lock taken here


def refuse_if_locked(folder: Path | str) -> None:
    """InputError naming the run that holds `folder`'s lock, if another one does: the check a
    command makes before its libraries load, so that a second run is refused at once (it takes
    the lock itself later; this creates nothing)."""
    holder = lock_holder(folder)
    if holder is not None:
        raise InputError(f"{Path(folder).resolve()}: {holder} is writing its outputs here; wait for it to end or choose "
                         "another output folder")


@contextlib.contextmanager
def folder_lock(folder: Path | str, command: str) -> Iterator[None]:
    """Hold the lock of `folder` (which must exist) while inside; InputError naming the other
    run when one holds it."""
    folder = Path(folder).resolve()  # one lock per folder, whatever link it is reached through
    held = _held.get(folder)
    if held is not None:
        held[1] += 1
    else:
        _held[folder] = [_acquire(folder, command), 1]
    try:
        yield
    finally:
        entry = _held[folder]
        entry[1] -= 1
        if entry[1] == 0:
            del _held[folder]
            # Remove the name while still holding the lock: a waiting run that opened the old
            # file sees it unnamed and starts again (see `_acquire`).
            try:
                os.unlink(folder / LOCK_NAME)
            except FileNotFoundError:
                pass
            except OSError as error:  # the folder made read-only meanwhile: the run's own error matters more
                logger.warning("%s: cannot be removed (%s); a later run replaces it", folder / LOCK_NAME, error.strerror)
            os.close(entry[0])
