"""Machine health from DIARC's on-line estimates: a two-sided CUSUM per parameter, judged only where excited.

:class:`MachineMonitor` (a simulate ``Observer``: chunk by chunk, bounded memory) and :func:`monitor_trace` (offline)
give the same numbers bit for bit. A parameter not excited or untrustworthy (:mod:`gantry_twin.health.excitation`)
is not judged: its CUSUM is frozen. h is in tolerance-seconds, not samples. (docs/health.md, "Health monitor")

The windows given in seconds (``baseline_window_s``, ``judge_from_s``) count from the first sample the monitor
sees: a run's t = 0, a log's first row, the first sample a shadow followed of a machine that was already running
(DIARC's estimator starts there from its initial estimates and needs the same settling time wherever that is;
docs/live-link.md, "Joining a running machine"). Alarms keep the trace's own time and also give the time since
that first sample.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from gantry_twin.health.excitation import (
    AXIS_OF,
    ExcitationSettings,
    FilteredRegressors,
    accumulate_information,
    accumulate_moment,
    estimate_bias,
    normalised_excitation,
    quantisation_noise,
)
from gantry_twin.health.tally import (  # noqa: F401 (the status codes are part of this module's interface)
    ALARM,
    BASELINE,
    DRIFTING,
    NOT_EXCITED,
    OK,
    STATUS_NAMES,
    UNTRUSTWORTHY,
    MonitorTally,
)
from gantry_twin.plant.model import THETA_NAMES, THETA_UNITS
from gantry_twin.settings import (
    Positive,
    Range,
    Seconds,
    Vector,
    Window,
    quote,
    signed_pct,
    validated,
)

#: Status codes of :attr:`MonitorReport.status` and their names: gantry_twin.health.tally.
#: The nominal disturbances dN1, dN2 (baseline ~0) are judged in volts, the rest relative.
ABSOLUTE_PARAMETERS = (6, 7)
#: The CUSUM statistics are capped at CUSUM_CAP * h, so that an alarm clears within about
#: CUSUM_CAP * h / (1 - |y|) seconds once the estimate is back inside the tolerance.
CUSUM_CAP = 2.0


# ---------------------------------------------------------------------------------------------
# Settings
# ---------------------------------------------------------------------------------------------


#: The monitor's settings that a scenario file also sets (its ``monitor`` mapping; the excitation's in excitation.py).
DecisionIntervalS = Range(0.0, 100.0, "s", lo_open=True)


@validated("health")
class HealthSettings:
    """The drift test.

    tolerance: per parameter, the CUSUM reference value k: relative for
    M, B, Af (0.10 = 10 %), volts for dN1, dN2.
    decision_interval_s: h, in tolerance-seconds (see the module docstring).
    baseline_window_s: when no baseline is given, the mean estimate over this
    window of the run (sampled every monitor period) is the baseline. The
    default starts at 20 s, after DIARC with the paper's estimator (kappa =
    0.1 1/s) has settled B and Af on the circle; an earlier baseline holds
    that transient, which then reads as a drift (docs/health.md, "Tunings").
    judge_from_s: first time a parameter is judged (None: the end of
    ``baseline_window_s``).
    Both count from the monitor's first sample (module docstring).
    """

    tolerance: Vector(Positive, THETA_NAMES) = (0.10, 0.10, 0.10, 0.10, 0.10, 0.10, 0.10, 0.10)
    decision_interval_s: DecisionIntervalS = 0.1
    baseline_window_s: Window = (20.0, 30.0)
    judge_from_s: Seconds | None = None

    @property
    def judge_start_s(self) -> float:
        return self.baseline_window_s[1] if self.judge_from_s is None else self.judge_from_s

    def first_judgement_s(self, baseline_given: bool) -> float:
        """Seconds after the first sample before anything can be judged: the judging start, and without a given
        baseline also the end of the baseline window (the baseline is taken there)."""
        return self.judge_start_s if baseline_given else max(self.judge_start_s, self.baseline_window_s[1])

    def not_reached(self, covered_s: float, baseline_given: bool) -> str:
        """What ``covered_s`` seconds from the first sample do not reach, in words naming the setting (for a
        one-line message); empty when they reach the first judgement."""
        need = self.first_judgement_s(baseline_given)
        if covered_s + 1e-9 >= need:
            return ""
        a, b = self.baseline_window_s
        if not baseline_given and need == b:
            return f"the monitor's baseline window {a:g}-{b:g} s (monitor.baseline_window_s)"
        return f"the monitor's judging start, {need:g} s (monitor.judge_from_s)"


@dataclass(frozen=True)
class Baseline:
    """The healthy machine's estimates theta_b (8,), volt units, and where they came from."""

    theta: tuple[float, ...]
    source: str = "given"

    def __post_init__(self) -> None:
        if len(self.theta) != 8 or not all(math.isfinite(x) for x in self.theta):
            raise ValueError(f"baseline.theta: must be eight finite numbers, got {quote(self.theta)}")
        for j, x in enumerate(self.theta):
            if j not in ABSOLUTE_PARAMETERS and x <= 0.0:
                raise ValueError(f"baseline.{THETA_NAMES[j]}: must be > 0 (a physical parameter), got {x}")

    @classmethod
    def from_mapping(cls, values: Mapping[str, float], source: str = "summary") -> Baseline:
        """From {name: value} as in a run summary (names as in THETA_NAMES)."""
        missing = [n for n in THETA_NAMES if n not in values]
        if missing:
            raise ValueError(f"baseline: missing {', '.join(missing)} (need all of {', '.join(THETA_NAMES)})")
        return cls(tuple(float(values[n]) for n in THETA_NAMES), source)

    def as_dict(self) -> dict[str, float]:
        return dict(zip(THETA_NAMES, self.theta, strict=True))


# ---------------------------------------------------------------------------------------------
# Results
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Alarm:
    """A raised alarm: the parameter, when, and how big the change is."""

    parameter: str
    time_s: float
    direction: str  # "up" or "down"
    estimate: float
    baseline: float
    change: float  # estimate - baseline, in ``unit``
    change_pct: float | None  # 100 change / baseline (None for dN1, dN2)
    unit: str
    cleared_s: float | None = None
    #: Seconds since the monitor's first sample (the clock of its windows; module docstring): ``time_s`` for a run
    #: from t = 0, less for a log cut from later or a shadow that joined a running machine.
    since_start_s: float | None = None

    def describe(self) -> str:
        pct = "" if self.change_pct is None else f" ({signed_pct(self.change_pct)})"
        since = self.since_start_s
        late = "" if since is None or abs(since - self.time_s) < 5e-3 else f" ({since:.2f} s after the first sample)"
        return (
            f"t = {self.time_s:.2f} s{late}: {self.parameter} {self.direction} {self.change:+.4g} {self.unit}{pct}: "
            f"estimate {self.estimate:.4g}, baseline {self.baseline:.4g}"
        )


@dataclass
class MonitorReport:
    """What the monitor saw, one row per monitor period (``t_s`` = end of the period).

    information (M, 2, 4, 4): int gamma_f gamma_f^T dt over the window, per axis, raw units.
    level_v (M, 2), parameter_v (M, 8): normalised excitation, volts (:mod:`gantry_twin.health.excitation`).
    moving (M, 2): fraction of the latest period each axis slid.
    excited (M, 8) bool; bias (M, 8): the bound of each estimate's relative bias from regressor
    errors (excitation.estimate_bias), trusted (M, 8) bool: excited and bias <= max_bias.
    Health (None without theta_hat): estimate (M, 8), deviation (M, 8) in tolerance units,
    cusum (M, 8, 2) [S+, S-], status (M, 8) codes into STATUS_NAMES; alarms in the order raised; baseline.
    """

    t_s: np.ndarray
    information: np.ndarray
    level_v: np.ndarray
    parameter_v: np.ndarray
    moving: np.ndarray
    excited: np.ndarray
    bias: np.ndarray | None = None
    trusted: np.ndarray | None = None
    estimate: np.ndarray | None = None
    deviation: np.ndarray | None = None
    cusum: np.ndarray | None = None
    status: np.ndarray | None = None
    alarms: list[Alarm] = field(default_factory=list)
    baseline: Baseline | None = None

    def _tally(self) -> MonitorTally:
        """These periods' totals."""
        return MonitorTally.of(self)

    def judged(self) -> list[str]:
        """The parameters the monitor judged at least once (status ok, drifting or alarm), in theta's order."""
        return self._tally().judged()

    def final_status(self) -> dict[str, str]:
        """The status of each parameter at the end of the run."""
        return self._tally().final_status()

    def time_in_status_s(self, period_s: float) -> dict[str, dict[str, float]]:
        """Seconds each parameter spent in each status."""
        return self._tally().time_in_status_s(period_s)


# ---------------------------------------------------------------------------------------------
# The monitor
# ---------------------------------------------------------------------------------------------


class MachineMonitor:
    """Excitation and health monitor; a simulate Observer, or offline via :func:`monitor_trace`.

    Working memory is bounded (filter states, the open period, the last
    window of per-period sums); the history it reports grows by one row per
    monitor period (``period_s``), not per sample.
    """

    def __init__(
        self,
        excitation: ExcitationSettings | None = None,
        health: HealthSettings | None = None,
        baseline: Baseline | None = None,
    ) -> None:
        self.excitation = excitation or ExcitationSettings()
        self.health = health or HealthSettings()
        self.given_baseline = baseline
        self._ready = False

    # -- Observer protocol --
    def on_start(self, run: object, trace) -> None:
        self._begin(trace)

    def on_chunk(self, trace, start: int, stop: int) -> None:
        if not self._ready:
            self._begin(trace)
        if start != self._next:
            raise ValueError(f"monitor: chunks must arrive in order; expected start {self._next}, got {start}")
        self._next = stop
        if stop <= start:
            return
        rows = trace.rows(start, stop)
        g, speed = self._regressors.advance(trace.q_meas_m[rows], trace.u_v[rows])
        weight = np.where(speed >= self.excitation.sliding_speed_m_s, self._ts, 0.0)
        most = (stop - start) // self._period + 1
        blocks = np.empty((most, 2, 4, 4))
        block_moving = np.empty((most, 2))
        m = accumulate_information(g, weight, start, self._period, self._acc, self._moving, blocks, block_moving)
        moments = np.empty((most, 2, 2, 4))  # the friction column's error (excitation.estimate_bias)
        error, size = self._regressors.friction_error, self._regressors.reversal_error
        accumulate_moment(g, error, size, weight, start, self._period, self._moment_acc, moments)
        theta = trace.controller_state.get("theta_hat")
        ends, infos, window_moments = [], np.empty((m, 2, 4, 4)), np.empty((m, 2, 2, 4))
        for i in range(m):
            self._closed += 1
            ends.append(self._closed * self._period - 1)  # global index of the period's last sample
            slot = self._ring_at % self._n_window
            self._ring[slot] = blocks[i]
            self._moment_ring[slot] = moments[i]
            self._ring_at += 1
            infos[i] = self._window_information()
            window_moments[i] = self._moment_ring[self._window_order()].sum(axis=0)
        level, param = normalised_excitation(infos, self._scale, self._window_s)
        bias = estimate_bias(param, self._scale, self._noise, infos, window_moments)
        for i, end in enumerate(ends):
            self._close_period(
                float(trace.t_s[end - trace.first]),
                infos[i],
                level[i],
                param[i],
                bias[i],
                block_moving[i],
                None if theta is None else theta[end - trace.first],
            )

    def on_end(self, trace) -> None:
        """Nothing to flush: a last, incomplete period is not reported."""

    # -- live views (for telemetry), cheap to call after every chunk --
    @property
    def alarms(self) -> list[Alarm]:
        """Alarms raised so far, in the order raised."""
        return list(self._alarms) if self._ready else []

    def excitation_since(self, row: int) -> tuple[np.ndarray, np.ndarray]:
        """Monitor periods from ``row`` on: (end times s (M,), excitation level per axis V (M, 2))."""
        if not self._ready:
            return np.zeros(0), np.zeros((0, 2))
        t = np.asarray(self._hist["t"][row:], dtype=float)
        return t, np.asarray(self._hist["level"][row:], dtype=float).reshape(-1, 2)

    def trusted_since(self, row: int) -> tuple[np.ndarray, np.ndarray]:
        """Monitor periods from ``row`` on: (end times s (M,), 1.0 where the estimate is trustworthy (M, 8))."""
        if not self._ready:
            return np.zeros(0), np.zeros((0, 8))
        t = np.asarray(self._hist["t"][row:], dtype=float)
        return t, np.asarray(self._hist["trusted"][row:], dtype=float).reshape(-1, 8)

    # -- results --
    def report(self, clear: bool = False) -> MonitorReport:
        """The periods so far; ``clear``: the periods since the last clearing, which are then dropped (the
        history's rows for :meth:`excitation_since` restart at 0; the alarms and baseline are kept)."""
        h = self._hist

        def stack(key: str, shape: tuple[int, ...]) -> np.ndarray:
            return np.array(h[key], dtype=float).reshape((-1, *shape))

        report = MonitorReport(
            t_s=np.array(h["t"]),
            information=stack("info", (2, 4, 4)),
            level_v=stack("level", (2,)),
            parameter_v=stack("param", (8,)),
            moving=stack("moving", (2,)),
            excited=stack("excited", (8,)).astype(bool),
            bias=stack("bias", (8,)),
            trusted=stack("trusted", (8,)).astype(bool),
            alarms=list(self._alarms),
            baseline=self._baseline,
        )
        if h["estimate"] or (clear and self._judged_before):
            report.estimate = stack("estimate", (8,))
            report.deviation = stack("deviation", (8,))
            report.cusum = stack("cusum", (8, 2))
            report.status = stack("status", (8,)).astype(np.int8)
        if clear:
            self._judged_before = self._judged_before or bool(h["estimate"])
            for rows in h.values():
                rows.clear()
        return report

    # -- internals --
    def _begin(self, trace) -> None:
        ex = self.excitation
        self._ts = trace.sample_period_s
        self._period = max(1, int(round(ex.period_s / self._ts)))
        self._period_s = self._period * self._ts
        self._n_window = max(1, int(round(ex.window_s / self._period_s)))
        self._window_s = self._n_window * self._period_s
        self._scale = np.asarray(ex.scale, dtype=float)
        self._regressors = FilteredRegressors(ex, self._ts)
        self._acc = np.zeros((2, 4, 4))
        self._moving = np.zeros(2)
        self._ring = np.zeros((self._n_window, 2, 4, 4))
        self._ring_at = 0
        self._noise = quantisation_noise(ex, ex.resolution_m, self._ts)
        self._moment_acc = np.zeros((2, 2, 4))
        self._moment_ring = np.zeros((self._n_window, 2, 2, 4))
        self._closed = 0
        self._next = 0
        self._origin_s = float(trace.t_s[0])  # the first sample's time: the windows count from it
        self._baseline = self.given_baseline
        self._baseline_sum = np.zeros(8)
        self._baseline_count = 0
        self._s = np.zeros((8, 2))
        self._alarmed = np.zeros(8, dtype=bool)
        self._alarms: list[Alarm] = []
        self._open_alarm: dict[int, int] = {}
        self._hist: dict[str, list] = {
            k: []
            for k in (
                *("t", "info", "level", "param", "bias", "moving", "excited", "trusted"),
                *("estimate", "deviation", "cusum", "status"),
            )
        }
        self._judged_before = False
        self._ready = True

    def _window_information(self) -> np.ndarray:
        """Sum of the last n_window period sums, oldest first (a fixed order: chunking-independent)."""
        return self._ring[self._window_order()].sum(axis=0)

    def _window_order(self) -> np.ndarray:
        """Ring slots of the window's periods, oldest first."""
        count = min(self._ring_at, self._n_window)
        return (self._ring_at - count + np.arange(count)) % self._n_window

    def _close_period(
        self,
        t: float,
        info: np.ndarray,
        level: np.ndarray,
        param: np.ndarray,
        bias: np.ndarray,
        moving: np.ndarray,
        theta: np.ndarray | None,
    ) -> None:
        ex = self.excitation
        excited = (param >= ex.min_parameter_v) & (moving[AXIS_OF] >= ex.min_moving_fraction)
        trusted = excited & (bias <= ex.max_bias)
        h = self._hist
        h["t"].append(t)
        h["info"].append(info)
        h["level"].append(level)
        h["param"].append(param)
        h["bias"].append(bias)
        h["moving"].append(moving.copy())
        h["excited"].append(excited)
        h["trusted"].append(trusted)
        if theta is not None:
            self._judge(t, np.asarray(theta, dtype=float), excited, trusted)

    def _judge(self, t: float, theta: np.ndarray, excited: np.ndarray, trusted: np.ndarray) -> None:
        hs = self.health
        half = 0.5 * self._ts
        since = t - self._origin_s  # the windows' clock
        if self._baseline is None:
            a, b = hs.baseline_window_s
            if a - half <= since < b - half:
                self._baseline_sum += theta
                self._baseline_count += 1
            elif since >= b - half and self._baseline_count:
                o = self._origin_s
                at = "" if o == 0.0 else f" from its first sample (t = {o + a:.6g}-{o + b:.6g} s)"
                self._baseline = Baseline(
                    tuple(float(x) for x in self._baseline_sum / self._baseline_count),
                    f"this run, mean over {a:g}-{b:g} s{at}",
                )
        status = np.full(8, BASELINE, dtype=np.int8)
        deviation = np.zeros(8)
        judging = self._baseline is not None and since >= hs.judge_start_s - half
        if self._baseline is not None:
            deviation = self._deviation(theta, np.asarray(self._baseline.theta))
        if judging:
            dt = self._period_s
            active = trusted
            cap = CUSUM_CAP * hs.decision_interval_s
            step_up = np.clip(self._s[:, 0] + (deviation - 1.0) * dt, 0.0, cap)
            step_down = np.clip(self._s[:, 1] + (-deviation - 1.0) * dt, 0.0, cap)
            self._s[:, 0] = np.where(active, step_up, self._s[:, 0])
            self._s[:, 1] = np.where(active, step_down, self._s[:, 1])
            h = hs.decision_interval_s
            for j in range(8):
                if not active[j]:
                    continue
                s_max = self._s[j].max()
                if not self._alarmed[j] and s_max > h:
                    self._alarmed[j] = True
                    self._raise(j, t, theta[j], int(np.argmax(self._s[j])))
                elif self._alarmed[j] and s_max == 0.0:
                    self._alarmed[j] = False
                    index = self._open_alarm.pop(j)
                    old = self._alarms[index]
                    self._alarms[index] = replace(old, cleared_s=t)
            s_max = self._s.max(axis=1)
            status = np.where(self._alarmed, ALARM, np.where(s_max > 0.0, DRIFTING, OK)).astype(np.int8)
            status[excited & ~trusted & ~self._alarmed] = UNTRUSTWORTHY
            status[~excited & ~self._alarmed] = NOT_EXCITED
        self._hist["estimate"].append(theta.copy())
        self._hist["deviation"].append(deviation)
        self._hist["cusum"].append(self._s.copy())
        self._hist["status"].append(status)

    def _deviation(self, theta: np.ndarray, base: np.ndarray) -> np.ndarray:
        tol = np.asarray(self.health.tolerance)
        relative = np.ones(8, dtype=bool)
        relative[list(ABSOLUTE_PARAMETERS)] = False
        denom = np.where(relative, tol * np.abs(np.where(relative, base, 1.0)), tol)
        return (theta - base) / denom

    def _raise(self, j: int, t: float, estimate: float, side: int) -> None:
        assert self._baseline is not None
        base = self._baseline.theta[j]
        change = float(estimate - base)
        pct = None if j in ABSOLUTE_PARAMETERS else 100.0 * change / base
        self._open_alarm[j] = len(self._alarms)
        direction = "up" if side == 0 else "down"
        unit, since = THETA_UNITS[j], t - self._origin_s
        self._alarms.append(Alarm(THETA_NAMES[j], t, direction, float(estimate), base, change, pct, unit, None, since))


def monitor_trace(
    trace,
    excitation: ExcitationSettings | None = None,
    health: HealthSettings | None = None,
    baseline: Baseline | None = None,
) -> MonitorReport:
    """Run the monitor offline over a finished trace (same result as the Observer)."""
    monitor = MachineMonitor(excitation, health, baseline)
    monitor.on_start(None, trace)
    monitor.on_chunk(trace, 0, trace.filled or trace.t_s.size)
    monitor.on_end(trace)
    return monitor.report()
