"""Critical sections that an interrupt (Ctrl-C, SIGTERM) cannot cut in two."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

#: the signals held back by :func:`interrupts_deferred`
DEFERRED_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back inside the block; one that came is handled at its end.

    Python runs a signal's handler between two bytecodes, so a Ctrl-C (KeyboardInterrupt) can
    land between two writes that belong together, such as the fields of one record of a log
    file. Inside this block the Python-level handlers of both signals only note a signal;
    at the end the handlers are put back and the first signal noted is passed to its own
    handler (a Python handler is called, a default action is taken again, an ignored signal
    stays ignored). Blocking the signals with ``pthread_sigmask`` would not do: the operating
    system hands a process-wide signal to any thread that does not block it (torch starts
    worker threads), and Python then runs its handler in the main thread all the same.

    Off the main thread, where handlers cannot be set (and where Python never runs them), and
    for a signal whose handler was not set from Python, this is a no-op.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[tuple[int, FrameType | None]] = []

    def note(signum: int, frame: FrameType | None) -> None:
        caught.append((signum, frame))

    previous: dict[int, Any] = {}
    try:
        for sig in DEFERRED_SIGNALS:
            handler = signal.getsignal(sig)
            if handler is not None:  # None: set outside Python, it could not be put back
                previous[sig] = signal.signal(sig, note)
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if caught:
            signum, frame = caught[0]
            handler = previous[signum]
            if callable(handler):
                handler(signum, frame)
            elif handler == signal.SIG_DFL:
                signal.raise_signal(signum)
