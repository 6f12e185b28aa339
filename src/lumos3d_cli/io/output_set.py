"""Everything one command writes, checked before any work and made visible in one commit.

A command declares its outputs up front — files and whole folders of its own inside one output
folder (restore: scene.ply, cameras.json, restored/, colmap/ ...), and files elsewhere (a video)
— together with its inputs. Before any work (`check`), and again right before the commit:

- every output path that exists must be lumos3d's own, unchanged since it was written (the
  folder's manifest, io/manifest.py); a folder of lumos3d's own (restored/) may hold nothing
  else. Anything else is the user's: the run is refused with a message naming it, and nothing
  is deleted or overwritten;
- no output is, contains or lies inside an input (a photo, a photo folder, a camera file, a
  checkpoint), and the output folder is not an input folder or inside one.

While the command runs it holds the output folders' locks (io/output_lock.py): a second run into
the same folder is refused instead of interleaving its files. Everything is written into one
hidden staging folder inside the output folder (files elsewhere: beside themselves), then
committed: a journal of the moves is written, and with the stop signals held back the old
outputs of this output set move into the staging folder and the new ones into place, the
manifest last, one rename each (a whole folder is one rename). Before the manifests, the old
outputs are checked again where they were moved: a file the user wrote among them after the last
check undoes the commit. A signal during the commit takes
effect once it is complete; a run killed outright during it (SIGKILL) is finished by
the next lumos3d run writing into that folder (io/atomic.py). Either way the folder holds the
complete old set or the complete new one.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import secrets
import shutil
import signal
import tempfile
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from lumos3d_cli.errors import STOP_SIGNALS, InputError, Interrupted
from lumos3d_cli.io.atomic import (
    COMMIT_JOURNAL,
    current_umask,
    folders_of_pending_commits,
    holds_unfinished_commit,
    is_leftover,
    make_folders,
    mark_pending_commit,
    remove_created_folders,
    remove_leftovers,
    remove_path,
    temporary_prefix,
    write_commit_journal,
)
from lumos3d_cli.io.manifest import MANIFEST_NAME, Manifest, describe_file
from lumos3d_cli.io.output_lock import LOCK_NAME, folder_lock, holds_a_lock_record, lock_holder, refuse_if_locked
from lumos3d_cli.io.output_paths import check_output_path

logger = logging.getLogger(__name__)

# Names lumos3d keeps for itself in an output folder: never an output, never the user's.
RESERVED_NAMES = frozenset({MANIFEST_NAME, LOCK_NAME})
# Errors of a full or unwritable disk: bad circumstances the user can fix, not internal errors.
DISK_ERRORS = {errno.ENOSPC: "no space left on the device", errno.EDQUOT: "the disk quota is exceeded",
                errno.EROFS: "the file system is read-only", errno.EACCES: "permission denied",
                errno.EFBIG: "a file grew beyond the system's file size limit"}


def _is_within(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def _resolved(path: Path) -> Path:
    try:
        return Path(path).expanduser().resolve(strict=False)
    except (RuntimeError, OSError) as error:  # a loop of links: Python 3.11 raises RuntimeError, 3.13 OSError ELOOP
        if isinstance(error, OSError) and error.errno != errno.ELOOP:
            raise
        raise InputError(f"{path}: its symbolic links lead round in a loop, to no file; fix or remove the link") from error


def _resolved_all(paths: Sequence[Path]) -> list[Path]:
    """`_resolved` of every path, each parent folder resolved once: a path that is not itself a
    link resolves to its resolved parent / its name (a render of 100,000 frames spent 9 s
    resolving each frame's path in full)."""
    parents: dict[Path, Path] = {}
    resolved = []
    for path in paths:
        path = Path(path).expanduser()
        if path.is_symlink() or path.name in ("", ".", ".."):
            resolved.append(_resolved(path))
            continue
        if path.parent not in parents:
            parents[path.parent] = _resolved(path.parent)
        resolved.append(parents[path.parent] / path.name)
    return resolved


def check_not_inputs(outputs: Sequence[Path], output_folders: Sequence[Path], inputs: Sequence[Path]) -> None:
    """InputError when an output file is an input or lies inside an input folder, or an output
    folder (one that lumos3d fills) is, contains or lies inside an input. Paths are compared after
    resolving links, so a link to an input is that input."""
    resolved_inputs = [(_resolved(path), path) for path in inputs if path is not None]
    input_folders = {resolved for resolved, _ in resolved_inputs if resolved.is_dir()}
    every_output = [*outputs, *output_folders]
    folders = set(output_folders)
    for output, target in zip(every_output, _resolved_all(every_output)):
        is_folder = output in folders
        for resolved, given in resolved_inputs:
            if target == resolved:
                raise InputError(f"{output}: is an input ({given}); lumos3d never writes over its inputs: choose another output")
            if is_folder and resolved.parent != resolved and _is_within(resolved, target):
                raise InputError(f"{output}: would hold the outputs, but it holds the input {given}; choose another output")
            if resolved in input_folders and _is_within(target, resolved):
                raise InputError(f"{output}: lies inside the input folder {given}; write the outputs outside the inputs")


@contextlib.contextmanager
def _stop_signals_held() -> Iterator[None]:
    """Hold back SIGINT, SIGTERM and SIGHUP while inside and deliver the first one afterwards,
    so that a commit, once started, completes. (Blocking the signals in this thread would not
    do: the kernel hands a process's signal to any thread that does not block it.)"""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    previous = {signum: signal.getsignal(signum) for signum in STOP_SIGNALS}
    held = [signum for signum, handler in previous.items() if handler is not signal.SIG_IGN]
    for signum in held:
        signal.signal(signum, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        for signum in held:
            signal.signal(signum, previous[signum])
        if pending:
            os.kill(os.getpid(), pending[0])


@dataclass
class _Item:
    """One output: its final path, where it is staged, its output set, whether it is a folder."""

    final: Path
    staged: Path | None
    output_set: str
    is_folder: bool = False


@dataclass
class Staging:
    """Where a command writes before the commit: `root` mirrors the output folder (write
    `root / name` for each declared file or folder); `files[final]` is the temporary path of a
    declared file outside it."""

    root: Path
    files: dict[Path, Path] = field(default_factory=dict)


class OutputSet:
    """The outputs of one command run in `folder` (see the module docstring). `output_set` names
    the group of files a re-run replaces (default: the command); `inputs` are the paths the
    outputs must stay clear of; `parameter` names the option of `folder` in messages."""

    def __init__(self, folder: Path | str, command: str, output_set: str | None = None,
                 inputs: Sequence[Path | str | None] = (), parameter: str = "output"):
        self.folder = Path(folder)
        self.command = command
        self.output_set = output_set or command
        self.inputs = [Path(path) for path in inputs if path is not None]
        self.parameter = parameter
        self._files: list[str] = []
        self._folders: list[str] = []
        self._elsewhere: dict[Path, str] = {}

    def add_file(self, name: str) -> OutputSet:
        """A file `name` (relative to the folder) this run writes."""
        self._files.append(name)
        return self

    def add_folder(self, name: str) -> OutputSet:
        """A folder that holds only this run's files (restored/): replaced whole; a file in it that
        lumos3d did not write refuses the run."""
        self._folders.append(name)
        return self

    def add_elsewhere(self, path: Path | str, output_set: str) -> OutputSet:
        """A file outside (or inside) the folder, in an output set of its own (a video)."""
        self._elsewhere[Path(path)] = output_set
        return self

    def paths(self) -> list[Path]:
        """Every output's final path."""
        return ([self.folder / name for name in [*self._files, *self._folders]] + list(self._elsewhere))

    def _folders_written(self) -> list[Path]:
        """The folders written into, once each (two names of one folder, through a link, count once)."""
        folders: dict[Path, Path] = {}
        for folder in [self.folder, *(path.parent for path in self._elsewhere)]:
            folders.setdefault(_resolved(folder), folder)
        return list(folders.values())

    # -- checks ---------------------------------------------------------------------------------

    def check(self) -> None:
        """InputError naming the path when the outputs cannot be written, would write over a file
        lumos3d did not write, or touch an input, or another run holds a folder: the check a
        command makes before its libraries load. Files a killed run left half committed are
        judged by `reserved`, which finishes the commit first under the folders' locks and checks
        the same again, as `staged` does once more before its commit."""
        self.check_paths()
        for folder in self._folders_written():
            refuse_if_locked(folder)
        # a killed run's commit half done: its files are judged once `reserved` has finished it
        if not any(holds_unfinished_commit(folder) for folder in self._folders_written()):
            self._check_ownership()

    def check_paths(self) -> None:
        """The checks that read no output: the outputs can be created, use no name lumos3d keeps
        for itself (a file of the user's under the manifest's name is read to tell), and stay clear
        of the inputs."""
        for folder in self._folders_written():
            check_output_path(folder, self.parameter if folder == self.folder else None, folder=True)
            for name in RESERVED_NAMES:
                own = folder / name
                # a file of the user's under the manifest's name was replaced by a manifest (the
                # lock's record is checked when the lock is taken)
                foreign_manifest = name == MANIFEST_NAME and own.is_file() and not Manifest.is_manifest(own)
                if own.is_symlink() or (own.exists() and not own.is_file()) or foreign_manifest:
                    raise InputError(f"{own}: is not lumos3d's {'lock' if name == LOCK_NAME else 'manifest'} file but "
                                     "takes its name; move it away or choose another output")
        for name in self._folders:  # moved whole at the commit: a read-only one failed only then, after the work
            path = self.folder / name
            if path.is_dir() and not path.is_symlink() and not os.access(path, os.W_OK | os.X_OK):
                raise InputError(f"{path}: is read-only, and this run replaces it; fix its permissions or choose "
                                 "another output")
        for path in self.paths():
            if path.name in RESERVED_NAMES:
                raise InputError(f"{path}: this name is lumos3d's own bookkeeping file; choose another name")
        for path in self._elsewhere:
            for name in self._folders:
                if _is_within(_resolved(path), _resolved(self.folder / name)):
                    raise InputError(f"{path}: lies inside {self.folder / name}, which holds only the outputs lumos3d "
                                     "puts there; choose another path")
        folder = _resolved(self.folder)
        for given in self.inputs:
            resolved = _resolved(given)
            if resolved.is_dir() and _is_within(folder, resolved):
                where = "is the input folder" if folder == resolved else "lies inside the input folder"
                raise InputError(f"{self.folder}: {where} {given}; write the outputs to another folder",
                                 parameter=self.parameter)
        check_not_inputs([*(self.folder / name for name in self._files), *self._elsewhere],
                         [self.folder / name for name in self._folders], self.inputs)

    def _check_ownership(self) -> None:
        manifests: dict[Path, Manifest] = {}

        def manifest(folder: Path) -> Manifest:
            if folder not in manifests:  # read once: a render of 3,000 frames read it 3,000 times a check
                manifests[folder] = Manifest.read(folder)
            return manifests[folder]

        for path in [*(self.folder / name for name in self._files), *self._elsewhere]:
            if not (path.exists() or path.is_symlink()):
                continue
            if path.is_dir() and not path.is_symlink():
                raise InputError(f"{path}: is a folder where lumos3d writes a file; move it away or choose another output")
            _refuse_unless_ours(manifest(path.parent), path)
        for name in self._folders:
            path = self.folder / name
            if not (path.exists() or path.is_symlink()):
                continue
            if path.is_symlink() or not path.is_dir():
                raise InputError(f"{path}: is a file where lumos3d writes its folder {name}/; move it away or choose "
                                 "another output")
            inside = sorted(path.rglob("*"))
            for lock in (inner for inner in inside if inner.name == LOCK_NAME):
                refuse_if_locked(lock.parent)  # a run writing in there now is named, not taken for the user's file
            for inner in inside:
                if _left_by_a_killed_run(inner, path):
                    continue  # lumos3d's own, replaced with the folder
                if inner.is_dir() and not inner.is_symlink():
                    raise InputError(f"{inner}: a folder lumos3d did not make, inside its output folder {path}; move it "
                                     "away or choose another output")
                if inner.name == MANIFEST_NAME and Manifest.is_manifest(inner):
                    continue
                # another run's output put there (`render -o out/restored`), listed by the manifest
                # beside it: lumos3d's, but not this run's to delete with the folder
                if inner.parent != self.folder and manifest(inner.parent).owns(inner):
                    entry = manifest(inner.parent).files[manifest(inner.parent).relative(inner)]
                    raise InputError(f"{inner}: an output of another lumos3d run ({entry.output_set}) inside {path}, "
                                     "which this run replaces whole; move it away or choose another output")
                _refuse_unless_ours(manifest(self.folder), inner)
        self._check_no_set_left_incomplete(manifest(self.folder))
        self._check_no_other_commands_output(manifest)

    def _check_no_other_commands_output(self, manifest: Callable[[Path], Manifest]) -> None:
        """InputError when a file this run writes is the output of another command: `render -o F`
        over the `degrade -o F/00000.png` there, `restore --video v.gif` over a render's v.gif.
        (A run of the same command may take over an earlier run's files: `restore -o out/b.ply`
        where a.ply was removed.)"""
        for path in [*(self.folder / name for name in self._files), *self._elsewhere]:  # (folders: `_check_ownership`)
            listing = manifest(path.parent)
            entry = listing.files.get(listing.relative(path))
            if entry is not None and entry.command != self.command and path.exists():
                raise InputError(f"{path}: an output of another lumos3d command ({entry.command}, {entry.output_set}) that "
                                 "this run would replace; lumos3d keeps other runs' outputs: move it away or choose "
                                 "another output")

    def _check_no_set_left_incomplete(self, manifest: Manifest) -> None:
        """InputError when this run would replace files of another output set of its folder while
        that set keeps others: `restore -o out/b.ply` after `restore -o out/a.ply` would give a.ply
        b's cameras.json, restored/ and summary.json."""
        ours = {*self._files, *self._folders}
        replaced = {entry.output_set for name, entry in manifest.files.items()
                    if name.split("/")[0] in ours and entry.output_set != self.output_set and (self.folder / name).exists()}
        for other in sorted(replaced):
            kept = sorted({name.split("/")[0] for name, entry in manifest.files.items()
                           if entry.output_set == other and name.split("/")[0] not in ours and (self.folder / name).exists()})
            if kept:
                raise InputError(f"{self.folder}: holds the outputs of {other} ({', '.join(kept)} and the files this run "
                                 "writes too); this run would replace those and leave the others unmatched: write to "
                                 "another folder, or move them away first", parameter=self.parameter)

    # -- writing --------------------------------------------------------------------------------

    @contextlib.contextmanager
    def reserved(self) -> Iterator[None]:
        """Check the paths, create the output folders and hold their locks while inside (a second
        run into them is refused), finish a commit a killed run left there (io/atomic.py), then
        check what is in the way — under the lock, so that another run's commit is never read half
        done. Folders this made are removed again when the block fails and they are empty."""
        self.check_paths()
        created: list[Path] = []
        with contextlib.ExitStack() as stack:
            try:
                for folder in self._folders_written():
                    created += make_folders(folder)
                    stack.enter_context(folder_lock(folder, self.command))
                for folder in self._folders_written():
                    # a killed commit into another folder that still needs this one's temporaries
                    # (its video) is finished first, under that folder's lock
                    for other in folders_of_pending_commits(folder):
                        try:
                            with folder_lock(other, self.command):
                                remove_leftovers(other, again=True)
                        except InputError as refusal:  # held by a live run, or no lock file can go there:
                            # its temporaries here stay (remove_leftovers keeps them) for a run into it
                            logger.info("%s; the killed commit into it stays unfinished for now", refusal)
                    # again, whatever this process cleaned before: another run may have died there since
                    remove_leftovers(folder, again=True)
                self._check_ownership()
                yield
            except BaseException:
                stack.close()  # the locks go first: their files would keep the folders from going
                remove_created_folders(created)
                raise

    @contextlib.contextmanager
    def staged(self) -> Iterator[Staging]:
        """Check, then yield the staging area; when the block succeeds check again and commit.
        When it raises (an interruption included) the staging area is removed and every output
        is as it was. A full or read-only disk, or an output that cannot be replaced, is an
        InputError naming the file."""
        with self.reserved():
            prefix = temporary_prefix("staging")
            earlier = {item.name for item in self.folder.iterdir() if item.name.startswith(prefix)}
            staging: Staging | None = None
            try:
                root = Path(tempfile.mkdtemp(prefix=prefix, suffix=".tmp", dir=self.folder))
                staging = Staging(root)
                for path in self._elsewhere:
                    handle, name = tempfile.mkstemp(prefix=temporary_prefix(path.stem), suffix=f".tmp{path.suffix}",
                                                    dir=path.parent)
                    os.close(handle)
                    staging.files[path] = Path(name)
                yield staging
                self.check_paths()  # again, under the lock, after the work: what changed meanwhile
                self._check_ownership()
                self._commit(staging)
            except OSError as error:
                reason = DISK_ERRORS.get(error.errno)
                if reason is None:
                    raise
                raise InputError(f"{error.filename or self.folder}: {reason} while writing the outputs (nothing was "
                                 "changed); free space, fix the permissions or choose another output") from error
            finally:
                # A signal can land after mkdtemp made the folder but before `staging` names it:
                # then the folder to remove is this process's staging folder that was not there before.
                roots = [staging.root] if staging is not None else [
                    item for item in self.folder.iterdir() if item.name.startswith(prefix) and item.name not in earlier]
                for root in roots:
                    shutil.rmtree(root, ignore_errors=True)
                for temporary in (staging.files.values() if staging is not None else ()):
                    temporary.unlink(missing_ok=True)

    def _items(self, staging: Staging) -> list[_Item]:
        declared = {*self._files, *self._folders}
        staged = {entry.name for entry in staging.root.iterdir()}
        undeclared = staged - declared
        if undeclared:
            raise ValueError(f"written but not declared as outputs: {sorted(undeclared)}")
        # folders resolved: a video through a link to the output folder is in that folder, whose
        # manifest lists it with the rest (two manifests of one folder dropped each other's files)
        items = [_Item(self.folder.resolve() / name, staging.root.absolute() / name, self.output_set, name in self._folders)
                 for name in sorted(staged)]
        return items + [_Item(final.absolute().parent.resolve() / final.name, temporary.absolute(), output_set, False)
                        for (final, output_set), temporary in zip(self._elsewhere.items(), staging.files.values())]

    def _commit(self, staging: Staging) -> None:
        """Move the staged outputs into place (module docstring): each old output out of the way
        and the new one in, stale files of the same output set out, each folder's manifest last,
        following a journal written beforehand. A move that fails undoes the ones before it."""
        items = self._items(staging)
        root = staging.root.absolute()
        trash = root / ".replaced"
        moves: list[tuple[Path, Path, str]] = []
        replaced: list[tuple[Path, Path, Path]] = []  # (old output, where it is moved, the folder listing it)
        previous_manifests: dict[Path, Manifest] = {}  # each folder's manifest before the commit
        manifest_moves: list[tuple[Path, Path, str]] = []  # last: after the old outputs are checked once moved
        leftovers: list[Path] = []  # old files moved beside themselves (outside the staging folder)
        staged_elsewhere: list[Path] = []  # manifests and markers outside the staging folder's: gone if no commit

        def move_away(path: Path, listing: Path) -> None:
            if _is_within(path.parent, self.folder.resolve()):
                destination = trash / str(len(moves))
            else:  # another folder (maybe another file system): beside itself, as a temporary of ours
                destination = path.parent / f"{temporary_prefix(path.name)}replaced_{len(moves)}_{_unique()}.tmp"
                leftovers.append(destination)
            moves.append((path, destination, "destination-exists"))
            replaced.append((path, destination, listing))

        for item in items:
            if item.final.exists() or item.final.is_symlink():
                move_away(item.final, item.final.parent)
            if not item.is_folder and not _is_within(item.staged, root):
                os.chmod(item.staged, 0o666 & ~current_umask())  # mkstemp made it private
            moves.append((item.staged, item.final, "source-gone"))
        inputs = set(_resolved_all(self.inputs))
        committed = False
        done: list[tuple[Path, Path]] = []  # the moves made (and not undone)
        try:
            written_sets = {(item.final.parent, item.output_set) for item in items}
            for folder in dict.fromkeys(item.final.parent for item in items):
                previous = previous_manifests[folder] = Manifest.read(folder)
                ours = [item for item in items if item.final.parent == folder]
                rewritten = {item.final.name for item in ours}
                manifest = Manifest(folder)
                for name, entry in previous.files.items():
                    if name.split("/")[0] in rewritten:
                        continue  # moved away above with the output it belongs to
                    if (folder, entry.output_set) in written_sets:
                        # A file of the set this run replaces that it did not write again (a view of an
                        # earlier run with more photos): stale; removed unless the user changed it, or
                        # this run read it (an input linking to it): inputs are never touched.
                        if previous.owns(folder / name) and _resolved(folder / name) not in inputs:
                            move_away(folder / name, folder)
                        elif previous.owns(folder / name):
                            manifest.files[name] = entry
                            logger.warning("%s: kept: an earlier run's output, and an input of this run", folder / name)
                        continue
                    if (folder / name).exists():
                        manifest.files[name] = entry
                for item in ours:
                    files = sorted(p for p in item.staged.rglob("*") if p.is_file()) if item.is_folder else [item.staged]
                    for file in files:
                        name = item.final.name + ("/" + file.relative_to(item.staged).as_posix() if item.is_folder else "")
                        manifest.files[name] = describe_file(file, self.command, item.output_set)
                number = len(moves) + len(manifest_moves)
                if _is_within(folder, self.folder.resolve()):
                    staged_manifest = root / f".manifest.{number}"
                else:  # another folder (a video's, maybe on another file system): staged beside its manifest
                    staged_manifest = folder / f"{temporary_prefix(MANIFEST_NAME)}manifest_{number}_{_unique()}.tmp"
                    staged_elsewhere.append(staged_manifest)
                staged_manifest.write_text(manifest.document())
                manifest_moves.append((staged_manifest, folder / MANIFEST_NAME, "source-gone"))
            first_manifest = len(moves)
            moves += manifest_moves
            # the other folders learn of the journal first: a run into them keeps what it still needs
            # (every folder but the output folder itself, compared resolved: a video in out/sub/ or
            # through a link to out/ is in out/sub/ and in out/)
            own = self.folder.resolve()
            markers = [mark_pending_commit(folder, root) for folder in dict.fromkeys(
                path.parent.resolve() for move in moves for path in move[:2] if not _is_within(path, root))
                if folder != own]
            leftovers += markers
            staged_elsewhere += markers
            trash.mkdir()  # before the journal: a full disk here fails with no journal to replay
            write_commit_journal(root, self.folder.absolute(), moves)
            with _stop_signals_held():
                try:
                    for index, (source, destination, _) in enumerate(moves):
                        if index == first_manifest:
                            # the old outputs are out of the way, where no one else writes: a file written
                            # into them since the last check (the user's) makes the commit undo itself
                            _check_still_ours(replaced, previous_manifests)
                        os.replace(source, destination)
                        done.append((source, destination))
                except InputError:
                    _undo(done)
                    done.clear()
                    raise
                except OSError as error:
                    _undo(done)
                    done.clear()
                    reason = DISK_ERRORS.get(error.errno) or error.strerror or type(error).__name__
                    raise InputError(f"{error.filename}: cannot be replaced ({reason}); nothing was changed: fix its "
                                     "permissions or choose another output") from error
                committed = True
                # the journal goes first: a run killed while the staging folder is removed must not
                # find it and "finish" moves whose trace (.replaced/N) is already gone
                (root / COMMIT_JOURNAL).unlink()
                shutil.rmtree(root, ignore_errors=True)
                for path in leftovers:
                    remove_path(path)
        except BaseException as stop:  # a signal, a refusal, or anything else (KeyboardInterrupt in the API)
            if isinstance(stop, Interrupted) and committed:  # a signal held over the moves lands after them
                stop.detail = stop.detail or f"after the outputs were written; {self.folder} holds the complete new outputs"
            elif not committed and not done:
                # the old outputs are in place (never moved, or moved back): the journal goes before
                # the staging folder (which `staged` removes), as after a commit, and what was staged
                # elsewhere with it (a run killed outright leaves both to the next run's clean-up)
                (root / COMMIT_JOURNAL).unlink(missing_ok=True)
                for path in staged_elsewhere:
                    path.unlink(missing_ok=True)
            raise


def _unique() -> str:
    """A random tag for a temporary name beside a file elsewhere: a killed run's and a later run's
    with the same process id (in a container, each run is process 1) must not collide."""
    return secrets.token_hex(4)


def _undo(done: list[tuple[Path, Path]]) -> None:
    """Move back, last first, what a failed commit moved: the old outputs return to their places."""
    for source, destination in reversed(done):
        try:
            os.replace(destination, source)
        except OSError:
            logger.error("could not move %s back to %s while undoing a failed commit", destination, source)


def _check_still_ours(replaced: list[tuple[Path, Path, Path]], manifests: dict[Path, Manifest]) -> None:
    """InputError naming the first old output that is no longer lumos3d's: a file the user changed
    or added in the moment between the ownership check before the commit and the moves, or a run
    that began writing inside a folder of outputs then. Checked on the old outputs where the commit
    moved them (the staging folder's trash, or beside themselves as temporaries), where no one else
    writes: what passes is what the commit may delete.

    replaced: (old output, where it lies now, the folder whose manifest lists it); manifests: those
    folders' manifests as they were before the commit."""
    for original, moved, listing in replaced:
        manifest = manifests[listing]
        folder_of_outputs = moved.is_dir() and not moved.is_symlink()
        if not folder_of_outputs:
            contents = [(moved, original)]
        else:  # a folder of outputs (restored/): judged as `_check_ownership` judged it in place
            contents = [(inner, original / inner.relative_to(moved)) for inner in sorted(moved.rglob("*"))]
            for inner, listed in contents:
                holder = lock_holder(inner.parent) if inner.name == LOCK_NAME else None
                if holder is not None:
                    raise InputError(f"{listed.parent}: {holder} began writing its outputs here while this run was "
                                     "committing its own; nothing was changed: run again once it has ended")
        for inner, listed in contents:
            if folder_of_outputs and _left_by_a_killed_run(inner, moved):
                continue
            if inner.name == MANIFEST_NAME and Manifest.is_manifest(inner):
                continue
            if manifest.holds(manifest.relative(listed), inner):
                continue
            raise InputError(f"{listed}: changed or made while this run was committing its outputs, so it is yours; "
                             "lumos3d never deletes what it did not write, and nothing was changed: move it away or "
                             "choose another output")


def _left_by_a_killed_run(inner: Path, folder: Path) -> bool:
    """Whether `inner` (inside the output folder `folder`) is what a killed lumos3d run writing in
    there left (`render -o out/restored` killed): its temporaries, and the lock file it held (no
    run holds it now: `refuse_if_locked` has refused a held one)."""
    parts = inner.relative_to(folder).parts
    return any(is_leftover(part) for part in parts) or (inner.name == LOCK_NAME and holds_a_lock_record(inner))


def _refuse_unless_ours(manifest: Manifest, path: Path) -> None:
    if manifest.owns(path):
        return
    if manifest.relative(path) in manifest.files:
        raise InputError(f"{path}: was changed since lumos3d wrote it, so it is yours now; lumos3d never overwrites or "
                         "deletes files it did not write: move it away or choose another output")
    outer = Manifest.read(path.parent.parent)  # an output inside another run's folder of outputs (restored/)
    if outer.owns(path):
        command = outer.files[outer.relative(path)].command
        raise InputError(f"{path}: an output of an earlier `{command}`, part of its outputs in {path.parent.parent}; "
                         "this run would take it over: choose another output")
    raise InputError(f"{path}: exists and was not written by lumos3d; lumos3d never overwrites or deletes files it did "
                     "not write: move it away or choose another output")
