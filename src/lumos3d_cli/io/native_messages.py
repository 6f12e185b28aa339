"""What C libraries print to the process's standard error while a call runs, captured: libjpeg
reports corrupt entropy-coded data only there (OpenCV decodes such a file to garbage and returns
it as an image), and libpng prints its own line before OpenCV returns nothing."""

from __future__ import annotations

import os
import sys
import tempfile
import threading
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

_lock = threading.Lock()  # one capture at a time: file descriptor 2 is the process's


def with_native_messages(call: Callable[[], T]) -> tuple[T, str]:
    """(call's result, what was written to file descriptor 2 during it). Another thread's writes
    in that window are captured too: the caller writes back what it does not use
    (`pass_on`). Where descriptor 2 cannot be duplicated (closed), the call runs uncaptured."""
    with _lock:
        sys.stderr.flush()
        try:
            saved = os.dup(2)
        except OSError:
            return call(), ""
        try:
            capture = tempfile.TemporaryFile()
        except OSError:  # no usable temporary folder: nothing is captured, nothing is lost
            os.close(saved)
            return call(), ""
        with capture:
            os.dup2(capture.fileno(), 2)
            try:
                result = call()
            finally:
                os.dup2(saved, 2)
                os.close(saved)
            capture.seek(0)
            return result, capture.read().decode("utf-8", errors="replace")


def pass_on(text: str) -> None:
    """Write captured text back to standard error, where it was going."""
    if text:
        os.write(2, text.encode("utf-8", errors="replace"))
