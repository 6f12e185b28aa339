"""Write outputs so that they appear whole or not at all: write under a temporary name, then rename.

Temporary names are hidden and carry the writing process's id, a tag of its host and its start
time, `.NAME.<pid>-<host>-<start>.XXXXXXXX.tmp[.suffix]`. A run that is killed outright (SIGKILL;
a power loss too, as far as the file system kept the renames: nothing here syncs folders)
cannot clean up after itself; the next run writing into the same folder recognises such
leftovers — their process no longer exists on this host, or its id now belongs to a process
that started at another time — and removes them, while the
temporaries of a run still going on (same host, live process) or of another host are left alone.

A leftover staging folder that holds a commit journal (io/output_set.py) was killed while it
moved its outputs into place: its remaining moves are finished first (roll forward), so the
folder holds the complete new set, then it is removed. A move that would replace a file made
since the kill, or move away an old output edited since, is left out: those are the user's.
The journal names its writer's start time and boot as well as its process id, which a live
process may have taken since (after a reboot; in a container every run may be process 1).
"""

from __future__ import annotations

import contextlib
import functools
import json
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
from lumos3d_cli.io.manifest import MANIFEST_NAME, Manifest, WrittenFile
from lumos3d_cli.io.output_paths import blocking_file

logger = logging.getLogger(__name__)

_HOST = f"{zlib.crc32(socket.gethostname().encode()):08x}"
# What follows ".NAME." in a temporary name: "<pid>-<host>-<start>.<random>.tmp", then an optional
# suffix (the start time, which tells a killed run from a live one of the same process id, is
# missing from an earlier release's names).
_OWNER = re.compile(r"\.(?P<pid>\d+)-(?P<host>[0-9a-f]{8})(?:-(?P<started>\d+))?\.[a-z0-9_]+\.tmp(\.[^.]*)?$")
# Folders already cleaned by this process: listing a folder again for every file written into it
# would cost O(files²) for a render of thousands of frames.
_cleaned: set[Path] = set()


def current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def temporary_prefix(name: str) -> str:
    """The start of this process's temporary names for an output called `name`."""
    return f".{name}.{owner_tag()}."


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


def owner_tag() -> str:
    """This process as temporary names and work folders carry it, "<pid>-<host>-<start time>" (0
    where the start time cannot be told): enough to tell a killed run's from a live one's, also
    when the process id has been reused (in a container every run may be process 1)."""
    return _own_tag(os.getpid())


@functools.lru_cache(maxsize=4)
def _own_tag(pid: int) -> str:
    """`owner_tag` of process `pid`, read from /proc once: every temporary name carries it (a
    render of thousands of frames), and a process's start time does not change."""
    return f"{pid}-{_HOST}-{_start_time(pid) or 0}"


def owner_has_ended(tag: str) -> bool:
    """Whether the process of an `owner_tag`, one on this host, has ended: its id is free, or taken
    by a process that started at another time. False for another host's, which cannot be told."""
    pid, host, started = (tag.split("-") + ["", "", ""])[:3]
    return pid.isdigit() and _has_ended(int(pid), host, started)


def _has_ended(pid: int, host: str, started: str | None) -> bool:
    if host != _HOST:
        return False
    if not _process_exists(pid):
        return True
    now = _start_time(pid)
    return started not in (None, "", "0") and now is not None and now != started


def is_leftover(name: str) -> bool:
    """True for a temporary of ours whose writer, a process on this host, has ended (its process
    id free, or taken by a process that started at another time)."""
    match = _OWNER.search(name)
    return name.startswith(".") and match is not None and _has_ended(int(match["pid"]), match["host"], match["started"])


def remove_path(path: Path) -> None:
    """Delete a file, a link (not what it points to) or a folder with everything in it; gone is fine."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


COMMIT_JOURNAL = ".commit.json"


def _real(path: Path) -> Path:
    """`path` with its folders resolved (no `..`, no link on the way; the last part kept as it is:
    a link among the outputs is moved, not followed)."""
    return Path(path).absolute().parent.resolve() / Path(path).name


def write_commit_journal(staging: Path, folder: Path, moves: list[tuple[Path, Path, str]]) -> None:
    """Write the journal of a commit into `staging` (inside the output `folder`) before its first
    move: the paths with their folders resolved (`-o ../out` would hold `..`, which a journal is
    not trusted with), the folder they belong to, and the other folders they may touch (a video
    elsewhere). Written to a temporary name and renamed, so a journal is whole or absent."""
    folder = Path(folder).resolve()
    moves = [(_real(source), _real(destination), done_when) for source, destination, done_when in moves]
    others = sorted({str(path.parent) for move in moves for path in move[:2] if not _is_inside(path, folder)})
    document = {"folder": str(folder), "other_folders": others, "writer": _writer_record(),
                "moves": [[str(source), str(destination), done_when] for source, destination, done_when in moves]}
    temporary = staging / f"{COMMIT_JOURNAL}.tmp"
    with open(temporary, "w") as handle:
        json.dump(document, handle)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temporary, staging / COMMIT_JOURNAL)


def _read_text(path: str) -> str | None:
    try:
        with open(path) as handle:
            return handle.read()
    except OSError:
        return None


def _boot_id() -> str | None:
    """This boot of the machine (Linux; None elsewhere)."""
    text = _read_text("/proc/sys/kernel/random/boot_id")
    return None if text is None else text.strip()


def _start_time(pid: int) -> str | None:
    """When process `pid` started, in clock ticks since boot (Linux; None when it does not exist
    or this cannot be told)."""
    text = _read_text(f"/proc/{pid}/stat")
    fields = None if text is None else text.rpartition(")")[2].split()
    return fields[19] if fields is not None and len(fields) > 19 else None


def _writer_record() -> dict:
    """Who writes a commit journal: its process id alone is not enough, as ids are reused (after
    a reboot, in containers), and a live process of the same id made a killed commit look alive."""
    return {"pid": os.getpid(), "boot": _boot_id(), "started": _start_time(os.getpid())}


def _journal_writer_ended(staging: Path) -> bool:
    """Whether the process that wrote `staging`'s journal has ended although a process of its id
    lives (another boot, or another start time): False when the journal says too little to tell."""
    try:
        writer = json.loads((staging / COMMIT_JOURNAL).read_text())["writer"]
        pid, boot, started = int(writer["pid"]), writer["boot"], writer["started"]
    except (OSError, ValueError, KeyError, TypeError):
        return False
    if boot is not None and _boot_id() is not None and boot != _boot_id():
        return True
    return started is not None and _start_time(pid) != started


def _is_killed_commit(entry: Path) -> bool:
    """A temporary of this host's whose writer has ended: by its name (`is_leftover`), or, for a
    staging folder holding a commit journal and for a marker naming one, by the journal's writer
    record when the process id has been reused by a live process."""
    if is_leftover(entry.name):
        return True
    match = _OWNER.search(entry.name)
    if not (entry.name.startswith(".") and match is not None and match["host"] == _HOST):
        return False
    if (entry / COMMIT_JOURNAL).is_file():
        return _journal_writer_ended(entry)
    if entry.name.startswith(".commit.") and entry.is_file():
        journal = _marker_journal(entry)
        return journal is not None and _journal_writer_ended(journal.parent)
    return False


def _is_inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def _journal_moves(staging: Path) -> list[tuple[Path, Path, str]] | None:
    """The moves of `staging`'s journal, or None when they cannot be trusted: an unreadable
    journal, one written for another folder (a copy of the output folder carries its journal
    along), or a path outside the journal's folders."""
    try:
        document = json.loads((staging / COMMIT_JOURNAL).read_text())
        folder, others = Path(document["folder"]), [Path(p) for p in document["other_folders"]]
        moves = [(Path(source), Path(destination), str(done_when)) for source, destination, done_when in document["moves"]]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not folder.is_absolute() or staging.absolute().parent.resolve() != folder.resolve():
        return None
    for move in moves:
        for path in move[:2]:
            inside = _is_inside(path, folder) or (path.parent in others and path.name != ".")
            if not path.is_absolute() or ".." in path.parts or not inside:
                return None
    return moves


def mark_pending_commit(folder: Path, staging: Path) -> Path:
    """Write into `folder` (another folder a commit touches: a video's) a marker naming the commit
    journal of `staging`, before the journal is written. While that journal exists, a run into
    `folder` keeps this process's temporaries there (the old video moved aside, the new one
    staged, the staged manifest): the killed commit still needs them (`remove_leftovers`)."""
    handle, name = tempfile.mkstemp(prefix=temporary_prefix("commit"), suffix=".tmp", dir=folder)
    with os.fdopen(handle, "w") as marker:
        json.dump({"journal": str(Path(staging).resolve() / COMMIT_JOURNAL)}, marker)
        marker.flush()
        os.fsync(marker.fileno())
    return Path(name)


def _marker_target(marker: Path) -> Path | None:
    """The commit journal a marker (`mark_pending_commit`) names; None for an unreadable marker."""
    try:
        return Path(json.loads(marker.read_text())["journal"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _marker_journal(marker: Path) -> Path | None:
    """The commit journal a marker names, while it exists; None for an unreadable marker (nothing
    it protects) or one whose journal is gone."""
    journal = _marker_target(marker)
    return journal if journal is not None and journal.name == COMMIT_JOURNAL and journal.is_file() else None


def _pending_journals(entries: list[Path]) -> dict[str, Path]:
    """{process id (as written in temporary names): its commit journal} of the killed runs whose
    commit, begun in another folder, is unfinished: their markers (`mark_pending_commit`) among
    `entries` name a journal that still exists."""
    journals = {}
    for entry in entries:
        if entry.name.startswith(".commit.") and _is_killed_commit(entry):
            journal = _marker_journal(entry)
            if journal is not None:
                journals[_OWNER.search(entry.name)["pid"]] = journal
    return journals


def _entries(folder: Path) -> list[Path]:
    """What `folder` holds; nothing when it is gone, no folder, or cannot be listed."""
    try:
        return list(Path(folder).iterdir())
    except OSError:
        return []


def folders_of_pending_commits(folder: Path | str) -> list[Path]:
    """The output folders whose killed commit still needs temporaries in `folder` (a video's):
    a run writing into `folder` finishes those commits first (`remove_leftovers` of each, under
    its lock)."""
    return list(dict.fromkeys(journal.parent.parent for journal in _pending_journals(_entries(folder)).values()))


def holds_unfinished_commit(folder: Path | str) -> bool:
    """Whether a killed run left `folder` mid-commit: a staging folder of its with a journal that
    can be finished here, or a marker of a journal in another folder that still exists. Its files
    are then neither the old set nor the new one until `remove_leftovers` finishes the commit,
    under the folder's lock."""
    entries = [entry for entry in _entries(folder) if _is_killed_commit(entry)]
    return (any((entry / COMMIT_JOURNAL).is_file() and _journal_moves(entry) is not None for entry in entries)
            or bool(set(_pending_journals(entries))))


_warned_mid_commit: set[Path] = set()


def warn_if_mid_commit(path: Path | str) -> None:
    """Warn (once per folder) when `path`, a file or folder a command reads, lies in an output
    folder, or in a folder of outputs inside one (restored/, colmap/), that a killed run left
    mid-commit: its files mix the earlier outputs and the killed run's until a run writing there
    finishes the commit. Reading commands write nothing there, so they only say so."""
    path = Path(path).absolute()
    folder = path if path.is_dir() else path.parent
    candidates = [folder]
    if any(name.startswith(f"{folder.name}/") for name in Manifest.read(folder.parent).files):
        candidates.append(folder.parent)  # a folder of outputs of the folder above (restored/, colmap/)
    for candidate in candidates:
        if candidate not in _warned_mid_commit and holds_unfinished_commit(candidate):
            _warned_mid_commit.add(candidate)
            logger.warning("%s: a run writing here was killed while it moved its outputs into place, so the files may "
                           "mix its outputs and an earlier run's; run that command into it again to finish", candidate)
            return


def finish_commit(staging: Path) -> bool:
    """Carry out the moves that `staging`'s commit journal lists and that have not happened;
    False (nothing moved) when the journal cannot be trusted (`_journal_moves`).

    A move of a new file into place is done when its source (in staging) is gone; a move of an
    old file out of the way is done when its destination (in staging's `.replaced`) exists —
    its source path is taken again by the new file, so "source gone" would not tell."""
    moves = _journal_moves(staging)
    if moves is None:
        return False
    output_folder = staging.absolute().parent.resolve()
    kept: list[Path] = []  # paths where the user's file stays instead of the commit's
    for source, destination, done_when in moves:
        done = destination.exists() if done_when == "destination-exists" else not (source.exists() or source.is_symlink())
        if done:
            continue
        if not (source.exists() or source.is_symlink()):  # removed since by hand: nothing to move
            logger.warning("%s: missing, so it cannot be moved to %s to finish a killed run's commit", source, destination)
            continue
        # The folder may have changed since the kill: an old output the user has edited (or
        # replaced) since is theirs and stays; a new output does not go where a file now is.
        if done_when == "destination-exists" and not _still_written_by_lumos3d(source, output_folder):
            logger.warning("%s: kept: changed since lumos3d wrote it, so it is yours now (a killed run's commit was "
                           "to replace it)", source)
            kept.append(source)
            continue
        if destination.name == MANIFEST_NAME:
            _drop_kept_from_manifest(source, destination.parent, kept)
        elif done_when == "source-gone" and (destination.exists() or destination.is_symlink()):
            if destination not in kept:
                logger.warning("%s: kept: made after a run was killed while writing it; that run's new %s was "
                               "dropped", destination, destination.name)
                kept.append(destination)
            continue
        destination.parent.mkdir(parents=True, exist_ok=True)
        os.replace(source, destination)
    return True


def _drop_kept_from_manifest(staged: Path, folder: Path, kept: list[Path]) -> None:
    """Rewrite the killed commit's staged manifest of `folder` before it goes into place: a path in
    `kept` holds the user's file (or an old output folder the user added to) instead of the
    commit's, so the commit's entries for it go; the old manifest's entries for files there that
    still hold what lumos3d wrote stay (an old restored/ kept whole keeps its views lumos3d's)."""
    names = [Manifest(folder).relative(path) for path in kept if _is_inside(path, folder)]
    if not names:
        return
    try:
        files = {entry: WrittenFile(**value) for entry, value in json.loads(staged.read_text())["files"].items()}
    except (OSError, ValueError, KeyError, TypeError):  # not ours to mend: moved in as it is
        return
    previous = Manifest.read(folder)

    def under(entry: str) -> bool:
        return any(entry == name or entry.startswith(f"{name}/") for name in names)

    mended = Manifest(folder, {entry: written for entry, written in files.items() if not under(entry)})
    mended.files.update({entry: written for entry, written in previous.files.items()
                         if under(entry) and previous.owns(folder / entry)})
    staged.write_text(mended.document())


def _still_written_by_lumos3d(path: Path, output_folder: Path) -> bool:
    """Whether `path` (a file, or a folder of outputs such as restored/) is what lumos3d wrote there,
    every file of a folder included. Judged by the nearest manifest that lists it: its own folder's
    (a file of the output folder, a video elsewhere or in a subfolder of its own), else one of the
    folders above it up to the output folder's, which lists its folders of outputs' files
    ("restored/1.png")."""
    folders = [path.parent]
    if _is_inside(path.parent, output_folder):
        folders += [folder for folder in path.parent.parents if _is_inside(folder, output_folder)]
    for folder in folders:
        manifest = Manifest.read(folder)
        name = manifest.relative(path)
        if path.is_dir() and not path.is_symlink():
            listed = {listed for listed in manifest.files if listed.startswith(f"{name}/")}
            if listed:
                present = {manifest.relative(file) for file in path.rglob("*") if not file.is_dir() or file.is_symlink()}
                return present <= listed and all(manifest.owns(folder / item) for item in present)
        elif name in manifest.files:
            return manifest.owns(path)
    return False


def _remove_commit_temporaries(moves: list[tuple[Path, Path, str]], journal: Path, folder: Path) -> None:
    """Remove, in the other folders a finished commit touched (a video's), what the killed run left
    there for it: the old files it moved aside, its staged manifest, its marker naming `journal`.
    Named one by one from the journal, without those folders' locks: only the dead run's own
    files, which no live run reads (a process of the same id may be a live run now)."""
    for move in moves:
        for path in move[:2]:
            if not _is_inside(path, folder) and _OWNER.search(path.name) and (path.exists() or path.is_symlink()):
                remove_path(path)
                logger.info("removed %s, left behind by an earlier run that was killed", path)
    for other in {path.parent for move in moves for path in move[:2] if not _is_inside(path, folder)}:
        for entry in _entries(other):
            if entry.name.startswith(".commit.") and _OWNER.search(entry.name) and _marker_target(entry) == journal:
                remove_path(entry)
                logger.info("removed %s, left behind by an earlier run that was killed", entry)


def remove_leftovers(folder: Path | str, again: bool = False) -> list[Path]:
    """Remove the temporaries in `folder` left by killed runs on this host (once per folder and
    process, unless `again`: a command's start), after finishing the commits they had begun;
    returns what was removed.

    The commits are finished first, each journal removed before its staging folder (a recovery
    cut short must not replay moves whose trace is gone), and only then the other temporaries
    go: a commit's video staged beside the staging folder is one of them until it is moved into
    place. Kept: the temporaries of a killed run whose commit is unfinished (a journal here that
    cannot be trusted or finished, or one in another folder that a marker here names)."""
    folder = Path(folder).absolute()
    if folder in _cleaned and not again:  # `again`: a command's start, where another run may have died since
        return []
    entries = [entry for entry in _entries(folder) if _is_killed_commit(entry)]
    _cleaned.add(folder)
    pending = set(_pending_journals(entries))
    removed = []
    for entry in [entry for entry in entries if (entry / COMMIT_JOURNAL).is_file()]:
        owner = _OWNER.search(entry.name)["pid"]
        if owner in pending:
            continue
        try:
            finished = finish_commit(entry)
        except OSError as error:  # a folder where a file goes, a file gone read-only: finished by hand
            logger.warning("%s: the commit of a killed run cannot be finished (%s); left as it is", entry, error)
            finished = False
        if not finished:
            logger.warning("%s: a commit journal of a killed run that does not belong here (a copied folder?), cannot "
                           "be read or cannot be finished; left as it is", entry)
            pending.add(owner)  # its temporaries beside it may still be the commit's
            continue
        logger.warning("finished moving the outputs of an earlier run into %s: it was killed while it did", folder)
        moves = _journal_moves(entry) or []
        journal = (entry / COMMIT_JOURNAL).resolve()
        (entry / COMMIT_JOURNAL).unlink()
        remove_path(entry)
        removed.append(entry)
        _remove_commit_temporaries(moves, journal, folder.resolve())  # its marker and old video elsewhere: garbage now
    for entry in entries:
        if entry in removed or not (entry.exists() or entry.is_symlink()):
            continue
        if _OWNER.search(entry.name)["pid"] in pending:
            logger.info("%s: kept for the unfinished commit of a killed run", entry)
            continue
        remove_path(entry)
        removed.append(entry)
        logger.info("removed %s, left behind by an earlier run that was killed", entry)
    return removed


def make_folders(folder: Path) -> list[Path]:
    """mkdir -p `folder`; returns the folders it created, outermost first (to undo on failure)."""
    missing = [parent for parent in [folder, *folder.parents] if not parent.exists()]
    blocker = blocking_file(folder / "output")
    if blocker is not None:  # commands check their outputs first (check_output_path); this is the last guard
        raise InputError(f"{folder}: cannot be created because {blocker} is a file, not a folder; choose another path")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:  # /proc, /sys, a read-only mount: no folder can be made there
        raise InputError(f"{folder}: cannot be created ({error.strerror}); choose another output") from None
    return missing[::-1]


def remove_created_folders(created: list[Path]) -> None:
    """Remove folders `make_folders` created, innermost first, where they are still empty."""
    for folder in reversed(created):
        with contextlib.suppress(OSError):
            folder.rmdir()


@contextlib.contextmanager
def atomic_path(final: Path | str) -> Iterator[Path]:
    """Yield a temporary path beside `final` (same suffix); rename it onto `final` when the block
    succeeds; when the block raises (an interruption included) delete it and any folder created
    for it."""
    final = Path(final)
    created = make_folders(final.parent)
    remove_leftovers(final.parent)
    handle, name = tempfile.mkstemp(prefix=temporary_prefix(final.stem), suffix=f".tmp{final.suffix}", dir=final.parent)
    os.close(handle)
    temporary = Path(name)
    try:
        yield temporary
        # mkstemp (and writers that replace the file, like safetensors) create 0600; outputs follow the umask
        os.chmod(temporary, 0o666 & ~current_umask())
        os.replace(temporary, final)
    except BaseException:
        temporary.unlink(missing_ok=True)
        remove_created_folders(created)
        raise


def write_bytes_atomic(final: Path | str, data: bytes) -> None:
    """Write `data` to `final` atomically."""
    with atomic_path(final) as temporary:
        temporary.write_bytes(data)
