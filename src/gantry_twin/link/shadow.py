"""Shadow mode: the twin follows a running machine over OPC UA, ``gantry-twin monitor --opcua`` (docs/live-link.md).

The machine's samples (blocks, or scalar values put together by their source time) go through the same
estimator and health monitor as ``monitor --log`` (:class:`gantry_twin.health.log_monitor.StreamMonitor`), a
chunk at a time, so that a live stream and its recorded log give the same estimates and alarms. The twin's
plant is driven by the machine's own commands in windows started from the measured state
(:func:`gantry_twin.sysid.replay.replay`) and the residual, measured minus predicted position, is reported per
window: the twin's fidelity, live.

Gaps are counted from the sample indices (a block's first index, or the time of a scalar sample), never filled:
the samples on either side of a gap are estimated as if they were consecutive. A sample with a NaN position
or command is dropped and counted. The trace is written as it comes, a part file every
:data:`PART_SAMPLES` samples (``trace/part-NNNNNN.parquet``, each complete on its own), so that a kill leaves a
readable trace of what came.

The monitor's windows (``baseline_window_s``, ``judge_from_s``) count from the first sample followed, not from the
machine's t = 0: the estimator starts there from its initial estimates (:mod:`gantry_twin.health.monitor`). A
reconnect goes on with the same estimator and windows; indices that go back (a machine's restart) end the stream.
Where ``--duration`` at the machine's pace cannot reach the first judgement, one line says so on connecting.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import numpy as np
import pyarrow as pa

from gantry_twin.health.log_monitor import StreamMonitor, estimate_window_s
from gantry_twin.health.monitor import MachineMonitor
from gantry_twin.health.tally import MonitorTally
from gantry_twin.link.blocks import SIGNAL_NAMES, Block
from gantry_twin.link.client import MachineClient, Received
from gantry_twin.link.nodemap import NodeMap
from gantry_twin.loop.trace import Observer, RunInfo, Trace
from gantry_twin.outputs.files import write_parquet
from gantry_twin.plant.model import AXES, Plant
from gantry_twin.sysid.logs import Log, LogChunk, LogInfo
from gantry_twin.sysid.replay import VELOCITY_FIT_S, WINDOW_S, replay
from gantry_twin.theta import THETA_NAMES

#: Samples handed to the estimator at once (0.2 s at 5 kHz), and at least every FEED_PERIOD_S of wall time.
FEED_SAMPLES = 1000
FEED_PERIOD_S = 0.2
#: Samples per trace part file (1 s at 5 kHz).
PART_SAMPLES = 5000
#: After the machine says ``finished``, how long to wait for what it sent before it, s.
FINISH_GRACE_S = 1.0
#: What ``live.ended_by`` says of a stop signal.
INTERRUPTED = "an interrupt (Ctrl-C or SIGTERM)"
#: The residual of each window, a CSV line each as they come (t_start_s, rms and max per axis, um).
RESIDUAL_FILE = "residual.csv"
COLUMNS = ("t_s", "x_m", "y_m", "u_x_v", "u_y_v", "x_d_m", "y_d_m")
BLOCK_COLUMNS = ("t_s", "x_meas_m", "y_meas_m", "u_x_v", "u_y_v", "x_d_m", "y_d_m")


class ShadowError(ValueError):
    """The stream cannot be judged (nothing came, only NaN, indices or times going back); one line."""


@dataclass
class Stream:
    """What has come so far."""

    period_s: float | None = None
    samples: int = 0
    first_index: int | None = None
    expected: int | None = None
    last_t: float = -math.inf
    gaps: int = 0
    missing: int = 0
    invalid: int = 0
    first_t: float | None = None
    ended_by: str = ""
    rows: list[np.ndarray] = field(default_factory=list)


class Shadow:
    """Follow ``endpoint``'s machine with DIARC's estimator ``controller`` and ``monitor``, its plant ``plant`` for
    the residual, a window of 1 s every ``residual_every_s`` of the machine's time (each costs a MuJoCo rollout of
    the rig's fine physics: every window would not keep up with a machine at 4x real time); write into ``out``
    (trace parts; the summary is the caller's). ``print_alarm`` is called with each new alarm as it is raised."""

    def __init__(
        self,
        endpoint: str,
        nodes: NodeMap,
        controller,
        monitor,
        plant: Plant,
        machine_period_s: float,
        out: Path,
        print_alarm: Callable[[object], None],
        stream: TextIO | None = None,
        residual_every_s: float = 5.0,
        observers: Sequence[Observer] = (),
        run_info: RunInfo | None = None,
    ) -> None:
        self.endpoint, self.nodes, self.controller, self.monitor = endpoint, nodes, controller, monitor
        self.plant, self.machine_period_s, self.out, self.print_alarm = plant, machine_period_s, out, print_alarm
        self.text = stream or sys.stderr
        self.s = Stream()
        self.tally = MonitorTally(trailing_s=10.0)
        self.estimator: StreamMonitor | None = None
        self._alarms_seen = 0
        self._part_rows: list[np.ndarray] = []
        self._parts = 0
        self._fed = 0
        self._residual_rows: list[np.ndarray] = []
        self.residual_every_s = residual_every_s
        self._next_residual_s = -math.inf
        self.residuals: list[tuple[float, np.ndarray, np.ndarray]] = []  # per window: start s, rms (2,), max (2,), m
        self._scalars: dict[float, dict[str, float]] = {}
        self._previous: int | None = None  # the first index of the last block of this connection
        self.connections = 0
        self.backlog_max = 0  # the most items received and not yet handled at once
        self.backlog: list[int] = []  # items waiting, read once a second
        self.observers, self.run_info = list(observers), run_info  # a dashboard: fed each chunk as a run's would be
        self._view: Trace | None = None  # the last chunk as the observers saw it
        self._duration_s: float | None = None

    def run(self, duration_s: float | None, first_connect_s: float, stop: threading.Event | None = None) -> None:
        """Follow the machine until ``duration_s`` of wall time, its run state ``finished`` or ``failed``, or
        ``stop`` (set by a stop signal: read between two chunks, so that the estimator and the monitor stop with
        their state whole; what came is kept). ShadowError when the stream cannot go on."""
        client = MachineClient(self.endpoint, self.nodes, first_connect_s).start()
        self._duration_s = duration_s
        end = math.inf if duration_s is None else time.monotonic() + duration_s
        finishing_at = math.inf
        next_feed = time.monotonic() + FEED_PERIOD_S
        next_backlog = time.monotonic()
        try:
            while True:
                now = time.monotonic()
                if stop is not None and stop.is_set():
                    self.s.ended_by = self.s.ended_by or INTERRUPTED
                    break
                if now >= end or now >= finishing_at:
                    self.s.ended_by = self.s.ended_by or "--duration"
                    break
                waiting = client.items.qsize()
                self.backlog_max = max(self.backlog_max, waiting)
                if now >= next_backlog:  # one reading a second: a backlog that grows shows in the row
                    self.backlog.append(waiting)
                    next_backlog = now + 1.0
                item = client.get(min(FEED_PERIOD_S, end - now, max(0.0, finishing_at - now)))
                if item is not None and not (item.kind in ("lost", "connected") and finishing_at < math.inf):
                    if self._take(item):  # a machine that finished closes its connection: not a loss
                        finishing_at = time.monotonic() + FINISH_GRACE_S
                if time.monotonic() >= next_feed or sum(r.shape[0] for r in self.s.rows) >= FEED_SAMPLES:
                    self._feed()
                    next_feed = time.monotonic() + FEED_PERIOD_S
        finally:
            client.stop()
            self._feed(final=True)
            self._write_part(final=True)
            if self._view is not None:
                for observer in self.observers:
                    observer.on_end(self._view)

    # -- what comes --
    def _take(self, item: Received) -> bool:
        """Handle one item; True when the machine said it finished."""
        if item.kind == "error":
            raise ShadowError(item.value)
        if item.kind == "connected":
            self.connections += 1
            self._period(item.value)
            self._previous = None  # a new subscription starts with the node's current value
        elif item.kind == "pace" and self.connections == 1:
            self._warn_short(item.value)
        elif item.kind == "lost":
            print(f"monitor: connection to {self.endpoint} lost ({item.value}); reconnecting", file=self.text)
        elif item.kind == "state":
            if item.value in ("finished", "failed"):
                self.s.ended_by = f"the machine's run state {item.value}"
                return True
        elif item.kind == "block":
            self._block(item.value)
        elif item.kind == "scalar":
            self._scalar(item.name, float(item.value), item.time_s)
        return False

    def _period(self, period: float | None) -> None:
        if period is None:
            raise ShadowError(f"--opcua {self.endpoint}: the server does not say its sample period; give --nodes FILE")
        if abs(period - self.machine_period_s) > 1e-9 * self.machine_period_s:
            raise ShadowError(
                f"--opcua {self.endpoint}: its sample period is {period:g} s, not the machine's "
                f"{self.machine_period_s:g} s that the estimator runs at"
            )
        self.s.period_s = period

    def _warn_short(self, pace: float | None) -> None:
        """One line, on the first connection, when ``--duration`` at the machine's ``pace`` (its seconds per
        wall-clock second; None: not known) ends before the monitor's first judgement."""
        if self._duration_s is None or pace is None:
            return
        covered = self._duration_s * pace
        note = short_of_judging(self.monitor, covered)
        if note:
            print(
                f"monitor: --duration {self._duration_s:g} s follows about {covered:.3g} s of the machine's time "
                f"(it runs at {pace:g}x real time): {note}; nothing will be judged",
                file=self.text,
                flush=True,
            )

    def _block(self, block: Block) -> None:
        s = self.s
        if self._previous is not None and block.first_index <= self._previous:
            raise ShadowError(
                f"--opcua {self.endpoint}: sample indices went back (a block from {block.first_index} after one "
                f"from {self._previous})"
            )
        self._previous = block.first_index
        if s.expected is None:
            s.expected = s.first_index = block.first_index
        if block.end_index <= s.expected:
            return  # the value a resubscription starts with: here already
        if block.first_index > s.expected:
            s.gaps += 1
            s.missing += block.first_index - s.expected
        skip = max(0, s.expected - block.first_index)
        rows = block.values[skip:, [SIGNAL_NAMES.index(c) for c in BLOCK_COLUMNS]]
        self._rows(rows)
        s.expected = block.end_index

    def _scalar(self, name: str, value: float, t: float) -> None:
        """Scalar values: a sample is complete when every signal has a value of the same source time."""
        key = round(t, 6)
        sample = self._scalars.setdefault(key, {})
        sample[name] = value
        if len(sample) == len(self.nodes.signals):
            del self._scalars[key]
            for old in [k for k in self._scalars if k < key]:
                del self._scalars[old]  # never completed: a missing value
                self.s.invalid += 1
            row = [key, sample["x_m"], sample["y_m"], sample["u_x_v"], sample["u_y_v"], math.nan, math.nan]
            if self.s.period_s and self.s.first_t is not None:
                index = int(round((key - self.s.first_t) / self.s.period_s))
                if self.s.expected is not None and index > self.s.expected:
                    self.s.gaps += 1
                    self.s.missing += index - self.s.expected
                self.s.expected = index + 1
            self._rows(np.array([row]))

    def _rows(self, rows: np.ndarray) -> None:
        s = self.s
        if rows.shape[0] == 0:
            return
        t = rows[:, 0]
        if t[0] <= s.last_t or np.any(np.diff(t) <= 0):
            raise ShadowError(f"--opcua {self.endpoint}: sample times went back (at t = {float(t[0]):.6g} s)")
        s.last_t = float(t[-1])
        good = np.isfinite(rows[:, :5]).all(axis=1)
        s.invalid += int((~good).sum())
        rows = rows[good]
        if rows.shape[0]:
            if s.first_t is None:
                s.first_t = float(rows[0, 0])
            s.rows.append(rows)
            s.samples += rows.shape[0]

    # -- what is done with it --
    def _feed(self, final: bool = False) -> None:
        s = self.s
        if not s.rows or s.period_s is None:
            return
        rows = np.concatenate(s.rows)
        if self.estimator is None and rows.shape[0] < 2:
            return  # the first chunk needs two samples (its first velocity)
        s.rows = []
        if self.estimator is None:
            self.estimator = StreamMonitor(self.controller, self.monitor, s.period_s, self.tally)
        desired = rows[:, 5:7] if np.isfinite(rows[:, 5:7]).all() else None
        chunk = LogChunk(self._fed, rows[:, 0], rows[:, 3:5], rows[:, 1:3], desired)
        trace = self.estimator.feed(chunk)
        self._fed += rows.shape[0]
        for alarm in self.monitor.alarms[self._alarms_seen :]:
            self.print_alarm(alarm)
        self._alarms_seen = len(self.monitor.alarms)
        self._show(trace)
        theta = trace.controller_state["theta_hat"]
        self._part_rows.append(np.column_stack([rows, theta]))
        self._write_part()
        self._residual(rows)

    def _show(self, trace: Trace) -> None:
        """Hand the chunk to the observers (a dashboard) as a run's chunk: the machine's measured position stands
        for the position (the twin cannot see the machine's true one) and its axial error is against the
        machine's desired position where it publishes one."""
        if not self.observers:
            return
        view = dataclasses.replace(trace, q_m=trace.q_meas_m, e_m=trace.q_d_m - trace.q_meas_m)
        if self._view is None:
            for observer in self.observers:
                observer.on_start(self.run_info, view)
        for observer in self.observers:
            observer.on_chunk(view, view.first, view.filled)
        self._view = view

    def _write_part(self, final: bool = False) -> None:
        held = sum(r.shape[0] for r in self._part_rows)
        if not held or (held < PART_SAMPLES and not final):
            return
        data = np.concatenate(self._part_rows)
        self._part_rows = []
        names = (*COLUMNS, *(f"theta_hat_{n}" for n in THETA_NAMES))
        table = pa.table({name: pa.array(data[:, j]) for j, name in enumerate(names)})
        self._parts += 1
        (self.out / "trace").mkdir(parents=True, exist_ok=True)
        write_parquet(self.out / "trace" / f"part-{self._parts:06d}.parquet", table)

    def _residual(self, rows: np.ndarray) -> None:
        """Replay the machine's commands through the twin's plant, one window of WINDOW_S every ``residual_every_s``
        of the machine's time (module docstring); the windows between are not replayed."""
        self._residual_rows.append(rows[:, :5])
        ts = self.s.period_s
        window = int(round(WINDOW_S / ts))
        need = window + 2 * max(1, int(round(0.5 * VELOCITY_FIT_S / ts))) + 2
        held = np.concatenate(self._residual_rows)
        while held.shape[0] >= need:
            start = float(held[0, 0])
            if start >= self._next_residual_s - 0.5 * ts:
                self._next_residual_s = start + self.residual_every_s
                self._replay_window(held[:need], ts)
            held = held[window:]
        self._residual_rows = [held]

    def _replay_window(self, rows: np.ndarray, ts: float) -> None:
        log = Log(self.endpoint, rows[:, 0], rows[:, 3:5], rows[:, 1:3], None, ts)
        r = replay(self.plant, log, WINDOW_S).residual_m
        covered = r[np.isfinite(r).all(axis=1)]
        if not covered.shape[0]:
            return
        rms, peak = np.sqrt((covered**2).mean(axis=0)), np.abs(covered).max(axis=0)
        self.residuals.append((float(rows[0, 0]), rms, peak))
        with open(self.out / RESIDUAL_FILE, "a", encoding="utf-8") as fh:  # a line a window, as they come
            if len(self.residuals) == 1:
                fh.write("t_start_s,rms_x_um,rms_y_um,max_x_um,max_y_um\n")
            fh.write(",".join(f"{v:.6g}" for v in (rows[0, 0], *(rms * 1e6), *(peak * 1e6))) + "\n")

    def live_section(self) -> dict:
        s = self.s
        ts = s.period_s
        out = {
            "endpoint": self.endpoint,
            "mode": self.nodes.mode,
            "sample_period_s": ts,
            "samples": s.samples,
            "first_index": s.first_index,
            "first_t_s": s.first_t,
            "covered_s": self.covered_s(),
            "gaps": s.gaps,
            "missing_samples": s.missing,
            "invalid_samples": s.invalid,
            "reconnects": max(0, self.connections - 1),
            "ended_by": s.ended_by or "--duration",
            "residual_windows": len(self.residuals),
            "backlog_max_items": self.backlog_max,
            "backlog_items_per_s": self.backlog,
        }
        if self.residuals:
            rms = np.sqrt(np.mean([r[1] ** 2 for r in self.residuals], axis=0)) * 1e6
            peak = np.max([r[2] for r in self.residuals], axis=0) * 1e6
            out["residual_rms_um"] = {a: float(v) for a, v in zip(AXES, rms, strict=True)}
            out["residual_max_um"] = {a: float(v) for a, v in zip(AXES, peak, strict=True)}
        return out

    def covered_s(self) -> float:
        """The machine's time from the first sample followed to the last: the clock of the monitor's windows."""
        s = self.s
        return float(s.last_t - s.first_t + s.period_s) if s.first_t is not None and s.period_s else 0.0

    def info(self) -> LogInfo:
        """The stream as a log's :class:`LogInfo` (for the estimate window and the summary)."""
        s = self.s
        return LogInfo(self.endpoint, s.samples, s.period_s or 0.0, s.first_t or 0.0, s.last_t, False)

    def finish(self) -> MonitorTally:
        """The tally, its estimate window closed over the stream's last 10 s (as ``monitor --log``'s)."""
        assert self.estimator is not None
        tally = self.estimator.finish()
        tally.close_window(estimate_window_s(self.info()))
        return tally


def short_of_judging(monitor: MachineMonitor, covered_s: float) -> str:
    """Which window ``covered_s`` seconds from the first sample followed end before, and what to do, for a one-line
    message; empty when they reach the health ``monitor``'s first judgement."""
    given = monitor.given_baseline is not None
    what = monitor.health.not_reached(covered_s, given)
    if not what:
        return ""
    need = monitor.health.first_judgement_s(given)
    longer = f"a --duration that covers {need:g} s of the machine's time"
    fix = longer if given else f"--baseline SUMMARY (a healthy run's or shadow's summary.json), or {longer}"
    return f"that ends before {what}, counted from the first sample followed; give {fix}"
