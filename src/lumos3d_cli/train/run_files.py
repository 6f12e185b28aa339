"""The files a training run replaces whole in its folder (run.json, config.yaml, the final and
selected weights, the validation pictures), listed in the folder's manifest (io/manifest.py) as
they are written, so that a resumed run replaces only what the run wrote and the user has not
changed since: an edited `final.safetensors` or a picture of the user's among `validation/`
refuses the resume, naming the file, instead of being overwritten.

A run folder from a release before the manifest lists none of its files: its resume takes the
run's files as the run's (with a warning) and lists them, so later resumes check them too.
"""

from __future__ import annotations

import logging
from pathlib import Path

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import write_bytes_atomic
from lumos3d_cli.io.manifest import MANIFEST_NAME, Manifest, describe_file

logger = logging.getLogger(__name__)

_COMMAND = "train"
_OUTPUT_SET = "training run"


class RunFiles:
    """The manifest of the run folder `output`."""

    def __init__(self, output: Path | str):
        self.output = Path(output)
        self.manifest = Manifest.read(self.output)
        # a folder whose manifest lists no file of a training run (none, or another command's):
        # a run of a release before the list, or a fresh one. An unreadable manifest is not that:
        # nothing in it counts as the run's, which refuses rather than replaces.
        path = self.output / MANIFEST_NAME
        readable = not (path.exists() or path.is_symlink()) or Manifest.is_manifest(path)
        self.unlisted = readable and not any(entry.command == _COMMAND for entry in self.manifest.files.values())

    def adopt_if_unlisted(self, written: list[Path]) -> None:
        """For a run folder of an earlier release: list the files its run wrote (`written`, those
        present), with a warning, so that this resume and later ones may replace them."""
        if not self.unlisted:
            return
        present = [path for path in written if path.is_file() and not path.is_symlink()]
        if present:
            logger.warning("%s lists no files (a run of an earlier release): its %d run file(s) are taken as the run's",
                           self.output, len(present))
        for path in present:
            self.record(path)

    def require_replaceable(self, paths: list[Path]) -> None:
        """InputError naming the first of `paths` that exists but is not a file this run wrote, as
        it wrote it."""
        for path in paths:
            if (path.exists() or path.is_symlink()) and not self.manifest.owns(path):
                raise InputError(f"{path}: was not written by this training run, or was changed since, and resuming "
                                 "would replace it; move it out of the run folder, then resume")

    def record(self, path: Path) -> None:
        """List `path` (just written by the run) in the folder's manifest."""
        self.manifest.files[self.manifest.relative(path)] = describe_file(path, _COMMAND, _OUTPUT_SET)
        write_bytes_atomic(self.output / MANIFEST_NAME, self.manifest.document().encode())
        self.unlisted = False

    def forget(self, path: Path) -> None:
        """Drop `path` (just removed by the run) from the manifest."""
        if self.manifest.files.pop(self.manifest.relative(path), None) is not None:
            write_bytes_atomic(self.output / MANIFEST_NAME, self.manifest.document().encode())
