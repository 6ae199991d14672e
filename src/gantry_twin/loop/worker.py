"""The loop in a worker process, for a controller that hosts foreign code (a native FMU): its faults are its own.

A controller FMU is native code run inside the 0.2 ms loop; it can crash (any signal), call ``exit()``, hang in a
call or leak memory. :class:`WorkerLoop` runs the loop (:mod:`gantry_twin.loop.simulate`'s chunks, the controller's
``reset`` and ``close`` with it) in a process forked from the command's, which waits for each chunk and watches:

* the worker ends (a signal, an exit status) before it answers: the run fails at the sample the foreign code was in,
  naming what ended it and the last call it was in (the controller's :class:`Isolation` progress);
* no sample finishes within ``call_timeout_s`` of wall time: the worker is killed, the run fails naming the call;
* the worker's resident memory passes ``memory_limit_bytes``: the worker is killed, the run fails saying so (a
  backstop also limits its address space to grow by at most twice that, so that a leak faster than the watch makes
  allocations fail rather than take the machine);
* a stop signal (SIGINT, SIGTERM, SIGHUP) reaches the command while it waits: the worker is killed at once (it
  ignores them itself) and the signal's exception goes on as in any run.

Every finished chunk comes back to the command's process (the recorded rows and the controller's logged values),
where the observers see it as in a run without a worker: a failed run keeps its samples up to the last chunk the
worker finished. The worker's temporary files live in a directory of its own, removed whatever the worker did.
The worker is forked: it starts with the command's memory (the plant, the compiled loop), so nothing is loaded
twice; the chunk kernel is loaded in the command's process before the fork (``Isolation.placeholders``).
"""

from __future__ import annotations

import contextlib
import mmap
import os
import select
import shutil
import signal
import socket
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any, NamedTuple, Protocol

import numpy as np

from gantry_twin.loop.process import (
    START_TIMEOUT_S,
    WATCH_S,
    become_worker,
    how_it_ended,
    resident_bytes,
    scratch_directory,
    sendable,
)
from gantry_twin.loop.trace import SimulationError, Trace

#: The shared progress row a hosted controller's step writes (:func:`shared_progress`): the call it is in (an index
#: into ``Isolation.calls``), the time s of the sample it is in, and how many samples it has started.
PROGRESS_CALL, PROGRESS_T_S, PROGRESS_SAMPLES = 0, 1, 2
#: How often, at least, a worker that answers is asked its memory, s (one that does not: every WATCH_S).
MEMORY_CHECK_S = 0.1


def shared_full(shape: tuple[int, ...], value: float) -> np.ndarray:
    """A float64 array of ``shape`` filled with ``value``, in memory shared with a worker forked later."""
    n = int(np.prod(shape))
    array = np.frombuffer(mmap.mmap(-1, max(8 * n, 8)), dtype=np.float64, count=n).reshape(shape)
    array.fill(value)
    return array


def shared_progress() -> np.ndarray:
    """A float64 (3,) row in memory shared with a worker forked later (an anonymous shared mapping); NaN time."""
    row = np.frombuffer(mmap.mmap(-1, 3 * 8), dtype=np.float64)
    row[PROGRESS_T_S] = np.nan
    return row


class Isolation(NamedTuple):
    """A controller's request to run in a worker process (its ``isolation`` attribute; :func:`isolation_of`).

    name: who the foreign code is, for the error line (an FMU's file name). call_timeout_s: wall time a sample's
    calls may take, s. memory_limit_bytes: the worker's resident memory at most. progress: the
    :func:`shared_progress` row the controller's step writes; calls: the name of each call index (0: none yet).
    placeholders: (params, state) of the compiled step's types, to load the chunk kernel before the fork (None:
    the Python loop).
    """

    name: str
    call_timeout_s: float
    memory_limit_bytes: int
    progress: np.ndarray
    calls: tuple[str, ...]
    placeholders: tuple[Any, Any] | None = None

    def where(self) -> tuple[str, float]:
        """The call the controller was last in (its name, '' if none yet) and that sample's time s (NaN: none)."""
        call = int(self.progress[PROGRESS_CALL])
        return (self.calls[call] if 0 <= call < len(self.calls) else ""), float(self.progress[PROGRESS_T_S])


def isolation_of(controller: object) -> Isolation | None:
    """The controller's :class:`Isolation` (its ``isolation`` attribute), None to run in the command's process
    (also where processes cannot be forked)."""
    found = getattr(controller, "isolation", None)
    return found if isinstance(found, Isolation) and hasattr(os, "fork") else None


class ChunkLoop(Protocol):
    """What simulate's loop offers: a piece to record into, samples run, the controller closed."""

    trace: Trace

    def hold(self, trace: Trace, rows: np.ndarray) -> None: ...

    def run(self, start: int, stop: int) -> tuple[int, SimulationError | None]: ...

    def close(self) -> None: ...


class WorkerLoop:
    """The loop of ``make_loop()`` run in a forked worker process, watched (module docstring).

    ``trace`` and ``rows``: the first piece and its packed reference (the worker inherits them); ``warm``: loads
    the chunk kernel here first; ``layout``: a compiled controller's log layout (its keys in this trace too).
    Made, it waits until the worker has reset the controller (its errors are raised here: a
    :class:`SimulationError` or the controller's own, as in-process; a worker that dies fails the run).
    """

    def __init__(
        self,
        make_loop: Callable[[], ChunkLoop],
        isolation: Isolation,
        trace: Trace,
        rows: np.ndarray,
        warm: Callable[[], None] | None = None,
        layout: tuple[tuple[str, tuple[int, ...]], ...] = (),
    ) -> None:
        if warm is not None:
            warm()
        self.isolation, self.trace, self._first, self._layout = isolation, trace, (trace, rows), layout
        self.pid, self._streamed, self._gone = 0, 0, None
        self.scratch = scratch_directory()
        self._checked = 0.0
        ours, theirs = socket.socketpair()
        try:
            isolation.progress[:] = (0.0, np.nan, 0.0)
            parent = os.getpid()
            self.pid = os.fork()
            if self.pid == 0:  # the worker: never returns
                ours.close()
                _worker(Connection(theirs.detach()), make_loop, isolation, trace, rows, self.scratch, parent)
            theirs.close()
            self.conn = Connection(ours.detach())
            self._poller = select.poll()  # one, for every wait (Connection.poll makes a selector each time)
            self._poller.register(self.conn.fileno(), select.POLLIN)
            self._answer("ready", max(isolation.call_timeout_s, START_TIMEOUT_S))
        except BaseException:
            ours.close()
            theirs.close()
            self.stop()
            raise

    def hold(self, trace: Trace, rows: np.ndarray) -> None:
        """Record into ``trace`` from now on (the worker, into a piece of its own like it)."""
        self.trace = trace
        if self._layout:
            trace.allocate_log(self._layout)
        message = (
            ("hold",)
            if self._first is not None and trace is self._first[0]
            else ("hold", trace.first, trace.t_s, rows, trace.disturbance_v, trace.true_theta)
        )
        self._first = None
        try:
            self._send(message)
        except SimulationError as error:  # the worker is gone: the piece's first chunk says so
            self._gone = error

    def run(self, start: int, stop: int) -> tuple[int, SimulationError | None]:
        """Samples [start, stop) in the worker; their rows copied into this trace (as :meth:`_Loop.run`).

        The first chunk of a piece asks the worker for the whole piece in chunks of this size: it runs ahead
        and hands each chunk over as it finishes (one message a chunk, none back), while this process shows the
        one before to the observers."""
        if self._gone is not None:
            return start, self._gone
        try:
            if start >= self._streamed:
                self._streamed = self.trace.first + self.trace.t_s.size
                self._send(("run", start, self._streamed, stop - start))
            done, failure, recorded, logged = self._answer("chunk")
        except SimulationError as error:  # the worker ended, hung or grew: nothing of this chunk came back
            return start, error
        rows = self.trace.rows(start, done)
        if recorded is not None:
            for name, values in zip(("q_m", "q_meas_m", "u_v"), recorded, strict=True):
                getattr(self.trace, name)[rows] = values
        state = self.trace.controller_state
        for key, values in logged.items():
            if key not in state:
                state[key] = np.full((self.trace.t_s.size, *values.shape[1:]), np.nan)
            state[key][rows] = values
        return done, None if failure is None else SimulationError(*failure)

    def close(self) -> None:
        """The controller closed in the worker, the worker ended; its error (an exception naming it) raised.
        Nothing to do once :meth:`stop` ended the worker."""
        if self.pid == 0:
            return
        try:
            self._send(("close",))
            why = self._answer("closed")
        except SimulationError as error:
            why = error.detail
        finally:
            self.stop()
        if why is not None:
            raise RuntimeError(why)

    def stop(self) -> None:
        """End the worker now (SIGKILL) if it runs, and remove its temporary files. Idempotent."""
        pid, self.pid = self.pid, 0
        if pid > 0:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            with contextlib.suppress(ChildProcessError):
                os.waitpid(pid, 0)
        if getattr(self, "conn", None) is not None:
            self.conn.close()
            self.conn = None
        shutil.rmtree(self.scratch, ignore_errors=True)

    # -- watching ------------------------------------------------------------------------------------------------

    def _send(self, message: tuple) -> None:
        try:
            self.conn.send(message)
        except OSError:  # the worker is gone: say how
            self._ended()

    def _answer(self, kind: str, limit_s: float | None = None) -> Any:
        """The worker's answer ``(kind, value)``; raised here: its exception, or why it ended, hung (no sample
        started for ``limit_s``, the call's time limit by default) or grew."""
        iso = self.isolation
        limit_s = iso.call_timeout_s if limit_s is None else limit_s
        seen, since = iso.progress[PROGRESS_SAMPLES], time.monotonic()
        while True:
            if self._poller.poll(WATCH_S * 1000):
                try:
                    got, value = self.conn.recv()
                except (EOFError, OSError):
                    self._ended()
                if got == "raise":
                    self.stop()
                    raise value
                if got != kind:
                    raise RuntimeError(f"the loop's worker answered {got!r} to {kind!r}")
                if time.monotonic() - self._checked > MEMORY_CHECK_S:
                    self._check_memory()
                return value
            now = time.monotonic()
            if iso.progress[PROGRESS_SAMPLES] != seen:
                seen, since = iso.progress[PROGRESS_SAMPLES], now
            elif now - since > limit_s:
                self._fail("", f" did not return within {limit_s:g} s (its time limit); stopped")
            self._check_memory()

    def _check_memory(self) -> None:
        self._checked = time.monotonic()
        resident = resident_bytes(self.pid)
        limit = self.isolation.memory_limit_bytes
        if resident > limit:
            self._fail(
                f"its process passed its memory limit of {limit / 2**20:.0f} MiB ({resident / 2**20:.0f} MiB "
                f"resident) in ",
                "; stopped",
            )

    def _ended(self) -> None:
        """The worker ended without answering: wait for it, and fail the run saying how."""
        pid, self.pid = self.pid, 0
        status = os.waitpid(pid, 0)[1] if pid > 0 else 0
        self._fail(f"{how_it_ended(status)} in ")

    def _fail(self, before: str, after: str = "") -> None:
        """Stop the worker and raise the run's error at the sample the controller was in: ``before``, the call it
        was in, ``after``; the error's ``detail`` is the FMU's part of the line."""
        self.stop()
        call, t_s = self.isolation.where()
        trace = self.trace
        ts = trace.sample_period_s
        k = trace.filled if not np.isfinite(t_s) or ts <= 0 else int(round(t_s / ts))
        k = min(max(k, trace.filled), trace.first + trace.t_s.size - 1)
        t_k = float(trace.t_s[trace.rows(k, k + 1)][0])
        detail = f"{self.isolation.name}: {before}{call or 'its first call'}{after}"
        error = SimulationError(f"the controller failed at t = {t_k:.4f} s (step {k}): {detail}", t_k, k)
        error.detail = detail
        raise error

    def __del__(self) -> None:
        if getattr(self, "pid", 0) > 0:
            self.stop()


# -- the worker ----------------------------------------------------------------------------------------------------


def _worker(
    conn: Connection,
    make_loop: Callable[[], ChunkLoop],
    isolation: Isolation,
    trace: Trace,
    rows: np.ndarray,
    scratch: str,
    parent: int,
) -> None:
    """The worker process: reset, then chunks on request, then close; ends with os._exit, never returns."""
    code = 0
    try:
        become_worker(isolation.memory_limit_bytes, scratch, parent)
        loop = make_loop()
        conn.send(("ready", None))
        while True:
            message = conn.recv()
            if message[0] == "run":  # [start, end) in chunks of ``size``, each handed over as it finishes
                start, end, size = message[1:]
                for first in range(start, end, size):
                    if not _chunk(conn, loop, first, min(end, first + size), trace):
                        break
            elif message[0] == "hold":
                loop.hold(*((trace, rows) if len(message) == 1 else _piece(*message[1:])))
            else:
                why = None
                try:
                    loop.close()
                except Exception as exc:
                    why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                conn.send(("closed", why))
                break
    except EOFError:  # the command's process went away
        code = 1
    except BaseException as exc:  # noqa: BLE001 -- the worker's errors are the command's to raise
        with contextlib.suppress(BaseException):
            conn.send(("raise", sendable(exc)))
        code = 1
    finally:
        os._exit(code)


def _chunk(conn: Connection, loop: ChunkLoop, start: int, stop: int, trace: Trace) -> bool:
    """Run samples [start, stop) and hand them over: the rows recorded (none for the first piece ``trace``: in
    shared memory, simulate allocates it with shared_full), the logged values, the failure; False if it failed."""
    done, error = loop.run(start, stop)
    piece, at = loop.trace, loop.trace.rows(start, done)
    recorded = None
    if piece is not trace:
        recorded = tuple(np.ascontiguousarray(a[at]) for a in (piece.q_m, piece.q_meas_m, piece.u_v))
    logged = {key: np.ascontiguousarray(v[at]) for key, v in piece.controller_state.items()}
    failure = None if error is None else (str(error), error.time_s, error.step)
    conn.send(("chunk", (done, failure, recorded, logged)))
    return error is None


def _piece(first: int, t_s: np.ndarray, rows: np.ndarray, disturbance_v: np.ndarray, true_theta: np.ndarray):
    """A piece of the run for the worker to record into: (trace, rows), the recorded arrays NaN."""
    n = t_s.size
    nan2 = np.full((n, 2), np.nan)
    piece = Trace(
        t_s=t_s,
        q_m=nan2.copy(),
        q_meas_m=nan2.copy(),
        q_d_m=nan2,
        e_m=nan2,
        eps_n_m=nan2[:, 0],
        eps_c_m=nan2[:, 0],
        u_v=nan2.copy(),
        disturbance_v=disturbance_v,
        true_theta=true_theta,
        filled=first,
        first=first,
    )
    return piece, rows
