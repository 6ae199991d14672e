"""The notice shown when a compiled loop will compile first: how long it should take, and the time so far.

:func:`compile_notice` asks :func:`gantry_twin.loop.simulate.loop_needs_compiling`
(numba's own cache, for this install path and machine); when a compile will
happen, the observer it returns writes one line on stderr as the run starts
and, when stderr is a terminal, counts the elapsed seconds on that line until
the first chunk of samples is done (the compile is over): ``run`` and
``excite``. A batch's driver (report, sweep, calibrate, tune) does the same
with :func:`batch_compile_notice` while its workers compile or load their
loops, before the first run; ``gantry-twin compile`` (:mod:`gantry_twin.cli.compile`) compiles ahead. All count
with a :class:`Ticker`.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from typing import TextIO

from gantry_twin.controllers import Controller
from gantry_twin.controllers.base import compiled_step_of
from gantry_twin.loop.simulate import loop_needs_compiling
from gantry_twin.loop.trace import RunInfo, Trace

#: Expected time of a cold compile of one controller's loop, s, at most: the slowest built-in loop (DIARC's, which
#: DRC and DARC share) from an empty cache on the slower of the 2-core VMs measured in docs/performance.md
#: ("Compile"), rounded up; also what a plug-in's loop is announced with (its step's size is unknown).
EXPECTED_COMPILE_S = 40
#: The same for the built-in pd's loop: 2.6 s of CPU on the quiet AMD EPYC VM of docs/performance.md, about three
#: times that at a load of 3 to 10, rounded up.
EXPECTED_PD_COMPILE_S = 10


def expected_compile_s(controller: Controller) -> int:
    """How long, at most, a cold compile of ``controller``'s loop is announced to take, s."""
    from gantry_twin.controllers.pd import pd_command

    compiled = compiled_step_of(controller)
    return EXPECTED_PD_COMPILE_S if compiled is not None and compiled.step is pd_command else EXPECTED_COMPILE_S


def compile_message(prog: str, expected_s: int = EXPECTED_COMPILE_S) -> str:
    """The line announcing a compile expected to take at most about ``expected_s`` seconds."""
    return f"{prog}: compiling the 0.2 ms loop for this install, once (at most about {expected_s} s)"


class Ticker:
    """One line on ``stream`` announcing work that takes a while (a compile), and on a terminal its seconds.

    Not a terminal: the line, once, as :meth:`start` is called. A terminal:
    the line followed by the seconds so far, rewritten every ``tick_s`` by a
    thread, ended with the total and "done" by :meth:`stop` (the first call;
    later ones return the same seconds). A context manager: started on
    entry, stopped on exit.
    """

    def __init__(self, message: str, stream: TextIO | None = None, tick_s: float = 0.5) -> None:
        self.message = message
        self.stream = stream if stream is not None else sys.stderr
        self.tick_s = tick_s
        self._done = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = 0.0
        self.elapsed_s = 0.0

    def start(self) -> None:
        self._started = time.monotonic()
        if not _is_terminal(self.stream):
            print(self.message, file=self.stream, flush=True)
            return
        self._write(0.0)
        self._thread = threading.Thread(target=self._tick, name="compile-notice", daemon=True)
        self._thread.start()

    def stop(self) -> float:
        """End the count (the total on a terminal); the seconds since :meth:`start`."""
        if self._done.is_set():
            return self.elapsed_s
        self._done.set()
        self.elapsed_s = time.monotonic() - self._started
        if self._thread is not None:
            self._thread.join()
            self._write(self.elapsed_s, " done\n")
        return self.elapsed_s

    def __enter__(self) -> Ticker:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _tick(self) -> None:
        while not self._done.wait(self.tick_s):
            self._write(time.monotonic() - self._started)

    def _write(self, elapsed_s: float, end: str = "") -> None:
        self.stream.write(f"\r{self.message}: {elapsed_s:.0f} s{end}")
        self.stream.flush()


class CompileNotice:
    """An Observer that announces a compile on ``on_start`` and, on a terminal, counts seconds until the first chunk.

    The line and the count are a :class:`Ticker`'s, stopped when the first
    chunk is recorded (or the run ends). ``compile_s``: the seconds from the
    run's start to its first chunk, the compile (and one chunk of samples),
    once the first chunk is done.
    """

    def __init__(
        self, prog: str, stream: TextIO | None = None, tick_s: float = 0.5, expected_s: int = EXPECTED_COMPILE_S
    ) -> None:
        self.ticker = Ticker(compile_message(prog, expected_s), stream, tick_s)
        self.compile_s = 0.0

    def on_start(self, run: RunInfo, trace: Trace) -> None:
        self.ticker.start()

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        self.compile_s = self.ticker.stop()

    def on_end(self, trace: Trace) -> None:
        self.compile_s = self.ticker.stop()


class CompileTimer:
    """An Observer that times a compile and says nothing: ``compile_s``, the seconds from the run's start to its first
    chunk (the compile and one chunk of samples), as :class:`CompileNotice` times it; for runs started from Python."""

    def __init__(self) -> None:
        self._started: float | None = None
        self.compile_s = 0.0

    def on_start(self, run: RunInfo, trace: Trace) -> None:
        self._started = time.monotonic()

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        self._stop()

    def on_end(self, trace: Trace) -> None:
        self._stop()

    def _stop(self) -> None:
        if self._started is not None:
            self.compile_s = time.monotonic() - self._started
            self._started = None


class _Quiet:
    """The Observer used when nothing compiles."""

    compile_s = 0.0

    def on_start(self, run: RunInfo, trace: Trace) -> None: ...

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None: ...

    def on_end(self, trace: Trace) -> None: ...


def compile_notice(controller: Controller, prog: str) -> CompileNotice | _Quiet:
    """A :class:`CompileNotice` if running ``controller`` will first compile its loop, else a quiet observer."""
    if not loop_needs_compiling(controller):
        return _Quiet()
    return CompileNotice(prog, expected_s=expected_compile_s(controller))


def compile_timer(controller: Controller) -> CompileTimer | _Quiet:
    """A :class:`CompileTimer` if running ``controller`` will first compile its loop, else a quiet observer."""
    return CompileTimer() if loop_needs_compiling(controller) else _Quiet()


def workers_compile_message(prog: str, loops: int, expected_s: int) -> str:
    """The line a batch's driver (report, sweep) prints when its workers will compile ``loops`` loops first, expected
    to take about ``expected_s`` seconds together."""
    what = "the loop" if loops == 1 else f"the {loops} loops"
    return (
        f"{prog}: workers compile {what} for this install, once per worker "
        f"(about {expected_s} s) before the first result"
    )


def batch_compile_notice(
    controllers: list[Controller], prog: str, stream: TextIO | None = None, tick_s: float = 0.5
) -> Ticker | contextlib.nullcontext[None]:
    """A :class:`Ticker` with :func:`workers_compile_message` if any of ``controllers``' loops will compile first
    (a context manager: enter it around the wait for the workers), else one that says nothing."""
    loops = {loop_of(c): expected_compile_s(c) for c in controllers if loop_needs_compiling(c)}
    if not loops:
        return contextlib.nullcontext()
    return Ticker(workers_compile_message(prog, len(loops), sum(loops.values())), stream, tick_s)


def loop_of(controller: Controller) -> object:
    """What identifies a controller's compiled loop: its compiled step and log (DRC, DARC and DIARC share one)."""
    compiled = compiled_step_of(controller)
    return (compiled.step, compiled.log) if compiled is not None else id(controller)


def _is_terminal(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False
