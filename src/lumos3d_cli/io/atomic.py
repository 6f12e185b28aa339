"""Write outputs so that they appear whole or not at all: temporary path, then rename."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(final: Path | str) -> Iterator[Path]:
    """Yield a temporary path beside `final` (same suffix); rename it onto `final` when the block
    succeeds, delete it when the block raises."""
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    handle, name = tempfile.mkstemp(prefix=f".{final.stem}.", suffix=f".tmp{final.suffix}", dir=final.parent)
    os.close(handle)
    temporary = Path(name)
    try:
        yield temporary
        # mkstemp (and writers that replace the file, like safetensors) create 0600; outputs follow the umask
        os.chmod(temporary, 0o666 & ~_current_umask())
        os.replace(temporary, final)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_directory(final: Path | str) -> Iterator[Path]:
    """Yield a temporary folder beside `final`; on success its files are moved into `final`
    (created if needed; files of the same name replaced), on failure it is removed."""
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".tmp", dir=final.parent))
    try:
        yield staging
        final.mkdir(parents=True, exist_ok=True)
        for item in sorted(staging.rglob("*")):
            target = final / item.relative_to(staging)
            if item.is_dir():
                target.mkdir(parents=True, exist_ok=True)
            else:
                os.replace(item, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def write_bytes_atomic(final: Path | str, data: bytes) -> None:
    """Write `data` to `final` atomically."""
    with atomic_path(final) as temporary:
        temporary.write_bytes(data)
