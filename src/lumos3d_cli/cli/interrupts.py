"""Stopping a command from outside — Ctrl-C (SIGINT), `kill` (SIGTERM), a closed terminal
(SIGHUP) — turns into an exception raised where the command is, so the cleanup that runs on any
failure runs here too: temporary outputs are removed (io/atomic.py), nothing half-written is
left. The CLI reports it in one line and exits with 128 + the signal number (130, 143, 129)."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator

from lumos3d_cli.errors import STOP_SIGNALS, Interrupted

# While `signals_raise_interrupted` is active: the function that installs its handlers again.
_claim: Callable[[], None] | None = None


def interruption_behind(error: BaseException) -> Interrupted | None:
    """The `Interrupted` that `error` was raised from, if any. Some code turns whatever stops it
    into its own error: a C extension interrupted while it initialises becomes an ImportError
    (and pycolmap's a RuntimeError saying to reinstall it); the cause is still the signal."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, Interrupted):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


@contextlib.contextmanager
def signals_raise_interrupted() -> Iterator[Callable[[], None]]:
    """While inside, SIGINT, SIGTERM and SIGHUP raise `Interrupted` in the main thread.

    Yields `claim`, which installs the handlers again: a library may install its own on import
    (pycolmap's logging library takes SIGTERM to print a stack dump and abort), so the caller
    claims the signals back once its imports are done.

    Only the first signal raises: later ones arrive while the cleanup runs and must not cut it
    short (SIGKILL still ends the process at once). A signal the process was started with
    ignored (`nohup` ignores SIGHUP) stays ignored. Off the main thread, where Python cannot
    install handlers (an embedding application), nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield lambda: None
        return
    raised = False

    def handler(signum, frame) -> None:
        nonlocal raised
        if not raised:
            raised = True
            raise Interrupted(signum)

    previous = {signum: signal.getsignal(signum) for signum in STOP_SIGNALS}
    handled = [signum for signum, old in previous.items() if old is not signal.SIG_IGN]

    def claim() -> None:
        for signum in handled:
            signal.signal(signum, handler)

    global _claim
    outer, _claim = _claim, claim
    claim()
    try:
        yield claim
    finally:
        _claim = outer
        for signum in handled:
            signal.signal(signum, previous[signum])


@contextlib.contextmanager
def library_imports() -> Iterator[None]:
    """Around a command's imports of the library, inside the command: they take seconds (torch,
    pycolmap, trimesh, viser...), so they happen when a command runs, not when the command line
    is parsed or `--help` shown. A library may install its own signal handlers on import
    (pycolmap's logging library takes SIGTERM to print a stack dump and abort), so the handlers of
    an active `signals_raise_interrupted` are installed again after them. Until then the stop
    signals are held back (blocked, not lost): one that arrives during the imports is delivered to
    our handler once it is back, instead of to the library's dump."""
    if _claim is None or threading.current_thread() is not threading.main_thread():
        yield
        return
    held = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
        _claim()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)
