"""The files a training run replaces whole in its folder (run.json, config.yaml, the final and
selected weights, the validation pictures), listed in the folder's manifest (io/manifest.py) as
they are written, so that a resumed run replaces only what the run wrote and the user has not
changed since: an edited `final.safetensors` or a picture of the user's among `validation/`
refuses the resume, naming the file, instead of being overwritten.

A run folder from a release before the manifest has none: its resume replaces as it always did
(with a warning), and lists what it writes from then on.
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
        self.unlisted = not (self.output / MANIFEST_NAME).is_file()

    def require_replaceable(self, paths: list[Path]) -> None:
        """InputError naming the first of `paths` that exists but is not a file this run wrote, as
        it wrote it (a run folder without a manifest: a warning, and nothing refused)."""
        present = [path for path in paths if path.exists() or path.is_symlink()]
        if self.unlisted:
            if present:
                logger.warning("%s lists no files (a run of an earlier release): resuming replaces %s as before",
                               self.output, ", ".join(path.name for path in present))
            return
        for path in present:
            if not self.manifest.owns(path):
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
