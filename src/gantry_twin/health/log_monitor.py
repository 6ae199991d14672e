"""The health monitor over a recorded log, no plant: ``gantry-twin monitor --log LOG`` (docs/logs.md).

DIARC's indirect estimator (eq. 25-28, :mod:`gantry_twin.controllers.arc`)
runs over the log's encoder positions and commands exactly as it runs in
the loop: at sample k it filters the position (first-order hold from
sample k-1), Sf of the backward-difference velocity and the command of
sample k-1 (what the DAC held over that interval), then takes the
least-squares step; sample 0 starts its filters. Its estimates theta^(t)
then go through the same :class:`gantry_twin.health.monitor.MachineMonitor` as a
simulated run's, with the scenario's estimator and monitor settings, and
give the same ``health`` section of summary.json and the same printed alarms.

On a twin's trace (float64 columns) the estimates are those the run
logged, to rounding (tests/test_logmonitor.py). The first sample's
velocity, which a log does not hold, is taken as the backward difference of
the first two samples; it only sets the filters' start.

The log is read a chunk at a time (:func:`gantry_twin.sysid.logs.log_chunks`), and the estimator and the
monitor carry their state from one chunk to the next; what is kept of the monitor's periods is their
:class:`~gantry_twin.health.tally.MonitorTally`, so memory does not grow with the log's length
(benchmarks/bench_log_memory.py).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from gantry_twin.controllers import DIARC
from gantry_twin.controllers.base import U_MAX_V, Measurement, RunContext
from gantry_twin.health.estimator_replay import estimator_replay
from gantry_twin.health.monitor import MachineMonitor
from gantry_twin.health.tally import MonitorTally
from gantry_twin.loop.trace import Trace
from gantry_twin.sysid.logs import Log, LogChunk, LogInfo

#: summary.json's estimates: the mean over the log's last ESTIMATE_WINDOW_S (at most half the log), s.
ESTIMATE_WINDOW_S = 10.0


class EstimatorReplay:
    """DIARC's estimator (its gains and estimator settings) over a log's chunks, in order: :meth:`estimates`."""

    def __init__(self, controller: DIARC, sample_period_s: float) -> None:
        self.controller, self.ts = controller, sample_period_s
        self._last: tuple[np.ndarray, np.ndarray] | None = None  # the previous chunk's last q_m and u_v
        self._args = None

    def estimates(self, chunk: LogChunk) -> np.ndarray:
        """theta^ (n, 8) after each sample of the chunk, volt units. The first chunk needs two samples."""
        q, u, ts = chunk.q_m, chunk.u_v, self.ts
        start = self._last is None
        dq = np.empty_like(q)
        if start:
            dq[1:] = np.diff(q, axis=0) / ts
            dq[0] = dq[1]
            context = RunContext(ts, np.array(U_MAX_V), Measurement(float(chunk.t_s[0]), q[0], dq[0]))
            self.controller.reset(context)
            params, state = self.controller.kernel_arguments()
            self._args = (params, state.theta, state.estimator)
            held = np.concatenate([u[:1], u[:-1]])
        else:
            q_before, u_before = self._last
            dq[:] = np.diff(np.concatenate([q_before[None], q]), axis=0) / ts
            held = np.concatenate([u_before[None], u[:-1]])
        out = np.empty((q.shape[0], 8))
        estimator_replay(*self._args, np.ascontiguousarray(q), dq, np.ascontiguousarray(held), start, out)
        self._last = (q[-1].copy(), u[-1].copy())
        return out


def estimates(controller: DIARC, log: Log) -> np.ndarray:
    """theta^ (n, 8) of DIARC's estimator over a whole log, volt units."""
    return EstimatorReplay(controller, log.sample_period_s).estimates(LogChunk(0, log.t_s, log.u_v, log.q_m, None))


def chunk_trace(chunk: LogChunk, theta_hat: np.ndarray, sample_period_s: float) -> Trace:
    """A trace piece of what the chunk holds (no true positions, no contour errors) with DIARC's estimates."""
    n = chunk.t_s.size
    nan2, nan = np.full((n, 2), np.nan), np.full(n, np.nan)
    return Trace(
        t_s=chunk.t_s,
        q_m=nan2,
        q_meas_m=chunk.q_m,
        q_d_m=chunk.q_d_m if chunk.q_d_m is not None else nan2,
        e_m=nan2,
        eps_n_m=nan,
        eps_c_m=nan,
        u_v=chunk.u_v,
        disturbance_v=np.zeros((n, 2)),
        true_theta=np.full(8, np.nan),
        controller_state={"theta_hat": theta_hat},
        filled=chunk.first + n,
        first=chunk.first,
        timestep_s=sample_period_s,
    )


def estimate_window_s(info: LogInfo) -> tuple[float, float]:
    """summary.json's estimates window: the log's last ESTIMATE_WINDOW_S, at most half of it."""
    return (info.t_last_s - min(ESTIMATE_WINDOW_S, 0.5 * info.duration_s), info.t_last_s)


def monitor_log(info: LogInfo, chunks: Iterable[LogChunk], controller: DIARC, monitor: MachineMonitor) -> MonitorTally:
    """DIARC's estimator and the health monitor over a log's chunks, one at a time (``info``: the log's
    :func:`~gantry_twin.sysid.logs.scan_log`); the tally of the monitor's periods (its alarms, statuses, the
    mean estimates over :func:`estimate_window_s`)."""
    stream = StreamMonitor(controller, monitor, info.sample_period_s, MonitorTally(estimate_window_s(info)))
    for chunk in _first_has_two(chunks):
        stream.feed(chunk)
    return stream.finish()


class StreamMonitor:
    """DIARC's estimator and the health monitor over a stream of chunks that arrive one at a time (a log read a
    chunk at a time, or a machine followed live): :meth:`feed` each in order, then :meth:`finish`. The first
    chunk needs two samples. ``on_chunk(trace, start, stop)``, when given, sees each chunk's trace piece with
    its estimates (a trace writer, a dashboard)."""

    def __init__(self, controller: DIARC, monitor: MachineMonitor, sample_period_s: float, tally: MonitorTally) -> None:
        self.replay = EstimatorReplay(controller, sample_period_s)
        self.monitor, self.ts, self.tally = monitor, sample_period_s, tally
        self.started = False

    def feed(self, chunk: LogChunk) -> Trace:
        """Estimate and judge one chunk; its trace piece (with theta_hat)."""
        trace = chunk_trace(chunk, self.replay.estimates(chunk), self.ts)
        if not self.started:
            self.monitor.on_start(None, trace)
            self.started = True
        self.monitor.on_chunk(trace, chunk.first, chunk.first + chunk.t_s.size)
        self.tally.add(self.monitor.report(clear=True))
        return trace

    def finish(self) -> MonitorTally:
        self.monitor.on_end(None)
        self.tally.add(self.monitor.report(clear=True))
        return self.tally


def _first_has_two(chunks: Iterable[LogChunk]) -> Iterator[LogChunk]:
    """The chunks, a one-row first chunk joined to the next (the first sample's velocity needs the second)."""
    pending: LogChunk | None = None
    for chunk in chunks:
        if pending is not None:
            desired = None if chunk.q_d_m is None else np.concatenate([pending.q_d_m, chunk.q_d_m])
            chunk = LogChunk(
                0,
                *(np.concatenate([a, b]) for a, b in ((pending.t_s, chunk.t_s), (pending.u_v, chunk.u_v))),
                np.concatenate([pending.q_m, chunk.q_m]),
                desired,
            )
            pending = None
        elif chunk.first == 0 and chunk.t_s.size < 2:
            pending = chunk
            continue
        yield chunk
