"""Stop signals: SIGINT, SIGTERM and SIGHUP held while a temporary file is named, raised as an exception, or (a
stream followed until stopped) set as a request that its loop reads.

The command line turns the first stop signal into :class:`Interrupted`, which
unwinds like Ctrl-C so that every ``except BaseException`` clean-up runs.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Iterator
from typing import Any

#: Signals the command line turns into an exception (cli.py); held while a temporary file is being created.
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Delay SIGINT, SIGTERM and SIGHUP until the block ends (where the platform allows)."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


class Interrupted(KeyboardInterrupt):
    """SIGINT, SIGTERM or SIGHUP arrived (``signum``): unwinds like Ctrl-C."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextlib.contextmanager
def stop_signals_interrupt() -> Iterator[None]:
    """In the block, the first SIGINT, SIGTERM or SIGHUP raises :class:`Interrupted`; later ones are ignored
    (the clean-up runs undisturbed). The previous handlers come back after the block."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: object) -> None:
        for stop in STOP_SIGNALS:
            signal.signal(stop, signal.SIG_IGN)
        raise Interrupted(signum)

    unraisable = sys.unraisablehook

    def keep_swallowed(info: Any) -> None:
        # A signal that lands in a C callback (numba's compile calls back into Python through ctypes) raises
        # there, and the callback can only print and drop the exception: keep it for raise_swallowed instead.
        if isinstance(info.exc_value, Interrupted):
            _SWALLOWED.append(info.exc_value)
        else:
            unraisable(info)

    previous = {stop: signal.signal(stop, interrupt) for stop in STOP_SIGNALS}
    sys.unraisablehook = keep_swallowed
    try:
        yield
    finally:
        sys.unraisablehook = unraisable
        _SWALLOWED.clear()
        for stop, handler in previous.items():
            signal.signal(stop, handler)


@contextlib.contextmanager
def stop_signals_request(requested: threading.Event) -> Iterator[None]:
    """In the block, the first SIGINT, SIGTERM or SIGHUP sets ``requested``, for a loop that checks it between two
    steps and stops where its state is whole (a stream followed a chunk at a time: an exception raised inside a
    chunk's bookkeeping would leave it half-done); a second one raises :class:`Interrupted`. The previous handlers
    come back after the block."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def request(signum: int, frame: object) -> None:
        if not requested.is_set():
            requested.set()
            return
        for stop in STOP_SIGNALS:
            signal.signal(stop, signal.SIG_IGN)
        raise Interrupted(signum)

    previous = {stop: signal.signal(stop, request) for stop in STOP_SIGNALS}
    try:
        yield
    finally:
        for stop, handler in previous.items():
            signal.signal(stop, handler)


#: Interrupted exceptions a C callback dropped (stop_signals_interrupt), raised again by raise_swallowed.
_SWALLOWED: list[Interrupted] = []


def raise_swallowed() -> None:
    """Raise again an :class:`Interrupted` that a C callback dropped, now that Python is in charge."""
    if _SWALLOWED:
        raise _SWALLOWED.pop()


class SwallowedInterrupt:
    """An Observer that calls :func:`raise_swallowed` at every chunk: a stop signal that arrived while the loop
    compiled stops the run at its first chunk, as one arriving a moment later would."""

    def on_start(self, run: Any, trace: Any) -> None:
        raise_swallowed()

    def on_chunk(self, trace: Any, start: int, stop: int) -> None:
        raise_swallowed()

    def on_end(self, trace: Any) -> None:
        raise_swallowed()
