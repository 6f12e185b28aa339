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

    claim()
    try:
        yield claim
    finally:
        for signum in handled:
            signal.signal(signum, previous[signum])
