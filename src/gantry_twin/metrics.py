"""What a run is judged by (paper section 5): contour error and estimate accuracy."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from gantry_twin.loop.trace import Trace
from gantry_twin.plant.model import THETA_NAMES


@dataclass(frozen=True)
class ContourMetrics:
    """rms and max of |eps_c| over a window, micrometres."""

    rms_um: float
    max_um: float
    window_s: tuple[float, float]


def window_mask(t_s: np.ndarray, window_s: tuple[float, float]) -> np.ndarray:
    """Samples with window[0] <= t < window[1]."""
    mask = (t_s >= window_s[0]) & (t_s < window_s[1])
    if not mask.any():
        raise ValueError(f"window {window_s} s holds no sample of a run of {t_s[-1]:.3f} s")
    return mask


def contour_metrics(trace: Trace, window_s: tuple[float, float]) -> ContourMetrics:
    """The paper's ||eps_c||_rms and eps_cM over the window."""
    return contour_metrics_of(trace.eps_c_m[window_mask(trace.t_s, window_s)], window_s)


def contour_metrics_of(eps_c_m: np.ndarray, window_s: tuple[float, float]) -> ContourMetrics:
    """:func:`contour_metrics` of the true contour errors eps_c (m) of the window's samples, in sample order."""
    eps = np.abs(eps_c_m) * 1e6
    return ContourMetrics(float(np.sqrt(np.mean(eps**2))), float(eps.max()), window_s)


class WindowMean:
    """The mean over the samples in a window of a series of rows (N, k), gathered chunk by chunk.

    The same floats as ``values[window_mask(t_s, window_s)].mean(axis=0)`` over
    the whole series, however it is cut: numpy sums axis 0 of such an array
    row after row, and the partial sum is carried on in the same order.
    """

    def __init__(self, window_s: tuple[float, float]) -> None:
        self.window_s = window_s
        self.count = 0
        self._sum: np.ndarray | None = None
        self._shape: tuple[int, ...] = ()

    def add(self, t_s: np.ndarray, values: np.ndarray) -> WindowMean:
        """Samples at times t_s (in order, after those added before) with their values (N, ...)."""
        rows = values[(t_s >= self.window_s[0]) & (t_s < self.window_s[1])]
        if rows.shape[0]:
            self.count += rows.shape[0]
            self._shape = rows.shape[1:]
            rows = rows.reshape(rows.shape[0], -1)
            if self._sum is not None:
                rows = np.concatenate([self._sum[None, :], rows])
            self._sum = np.add.reduce(rows, axis=0)
        return self

    def mean(self) -> np.ndarray:
        """The mean (the shape of one row); ValueError if no sample was in the window."""
        if self._sum is None:
            raise ValueError(f"window {self.window_s} s holds no sample of the run")
        return (self._sum / self.count).reshape(self._shape)


def steady_estimates(trace: Trace, window_s: tuple[float, float]) -> np.ndarray | None:
    """Mean theta^ over the window (e.g. the last period), or None if not estimated."""
    theta = trace.controller_state.get("theta_hat")
    if theta is None:
        return None
    return WindowMean(window_s).add(trace.t_s, theta).mean()


def steady_true_parameters(trace: Trace, window_s: tuple[float, float]) -> np.ndarray:
    """Mean true theta over the same window (volt units), the value :func:`steady_estimates` is judged against.

    It moves when the run has plant changes (a payload picked up, drifting
    friction); a window before the change is judged against the old value.
    """
    return WindowMean(window_s).add(trace.t_s, trace.true_parameters_t()).mean()


def carried_sum(carry: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``carry`` (k,) plus the rows (n, k) added one after another, row by row.

    Sequential (``np.cumsum``, not numpy's pairwise sum), so a series summed in
    pieces gives the same bits as the whole series summed at once.
    """
    if rows.shape[0] == 0:
        return carry
    return np.cumsum(np.concatenate([carry[None, :], rows]), axis=0)[-1]


@dataclass(frozen=True)
class WholeRunMetrics:
    """What a run did after its first period, and its commands over the whole run.

    window_s: [start of the paper's window (by default t0 + T), end of the run];
    contour_rms_um, contour_max_um: rms and max of abs(eps_c) over it;
    axial_rms_um (X, Y): rms of e = q - q_d over it, micrometres;
    command_window_s: [0, end]; max_abs_command_v (X, Y): largest abs(u) of the
    command as applied, volts (its saturation: :class:`gantry_twin.loop.events.TravelWatch`);
    periods_start_s, period_s, period_rms_um: rms of abs(eps_c) over each period
    [start + k T, start + (k + 1) T) from the end of the start ramp, the last
    one up to the end of the run (shorter when the run is not whole periods).
    """

    window_s: tuple[float, float]
    contour_rms_um: float
    contour_max_um: float
    axial_rms_um: tuple[float, float]
    command_window_s: tuple[float, float]
    max_abs_command_v: tuple[float, float]
    periods_start_s: float
    period_s: float
    period_rms_um: tuple[float, ...]


class RunMetrics:
    """What summary.json judges a run by, gathered chunk by chunk (an Observer): the contour error over
    ``contour_window_s``, the mean estimate and true theta over ``estimate_window_s`` and, when ``run_window_s``
    and ``periods_s`` are given, the figures of :class:`WholeRunMetrics`.

    Holds the window's eps_c (8 bytes per sample in it), two running sums, and
    for the whole run a few running sums and maxima plus two numbers per period,
    so a run held in pieces is judged as a whole trace would be, to the bit.
    """

    def __init__(
        self,
        contour_window_s: tuple[float, float],
        estimate_window_s: tuple[float, float],
        run_window_s: tuple[float, float] | None = None,
        periods_s: tuple[float, float] | None = None,
        confidence: Any = None,
        excluded_s: Sequence[tuple[float, float]] = (),
    ) -> None:
        """confidence: an Observer with ``verdicts(estimate)``
        (:class:`gantry_twin.health.confidence.EstimateConfidence`) fed the same chunks, or None (no
        trustworthiness in the summary). excluded_s: time intervals [a, b) s whose samples count in no contour
        figure (a part program's rapid moves, docs/gcode.md)."""
        self.contour_window_s, self.estimate_window_s = contour_window_s, estimate_window_s
        self.run_window_s, self.periods_s = run_window_s, periods_s
        self.excluded_s = tuple((float(a), float(b)) for a, b in excluded_s)
        self.confidence = confidence
        self._eps_c: list[np.ndarray] = []
        self._theta = WindowMean(estimate_window_s)
        self._true = WindowMean(estimate_window_s)
        self._estimated = False
        # Whole run: sums of squares (um^2) of eps_c and e_x, e_y in run_window_s, their count, max abs(eps_c).
        self._run_sq = np.zeros(3)
        self._run_count = 0
        self._run_max_um = 0.0
        self._max_abs_u_v = np.zeros(2)
        self._period_sq: list[np.ndarray] = []  # per period: [sum of eps_c^2 um^2]
        self._period_count: list[int] = []

    @classmethod
    def for_scenario(cls, scenario: Any, confidence: Any = None) -> RunMetrics:
        """The metrics summary.json holds for a :class:`gantry_twin.scenario.Scenario`: its windows, the whole
        run from the start of its contour window, its periods from the end of the start ramp; ``confidence``
        as in the constructor."""
        window = scenario.metric_window_s
        periods = (scenario.timing_law().settled_s, scenario.period_s)
        return cls(window, scenario.estimate_window_s, (window[0], float(scenario.duration_s)), periods, confidence)

    @classmethod
    def for_program(cls, scenario: Any, rapids_s: Sequence[tuple[float, float]], confidence: Any = None) -> RunMetrics:
        """The metrics of a part program's run: as :meth:`for_scenario`, its rapid moves ``rapids_s`` left out
        of every contour figure, and no per-period figures (a program has no lap)."""
        window = scenario.metric_window_s
        return cls(
            window, scenario.estimate_window_s, (window[0], float(scenario.duration_s)), None, confidence, rapids_s
        )

    def _counted(self, t: np.ndarray) -> np.ndarray:
        """Which samples count in the contour figures: those outside every excluded interval."""
        keep = np.ones(t.shape, dtype=bool)
        for a, b in self.excluded_s:
            keep &= ~((t >= a) & (t < b))
        return keep

    def on_start(self, run: object, trace: Trace) -> None:
        pass

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        rows = trace.rows(start, stop)
        t = trace.t_s[rows]
        w = self.contour_window_s
        eps_c_m = trace.eps_c_m[rows]
        counted = self._counted(t)
        self._eps_c.append(eps_c_m[(t >= w[0]) & (t < w[1]) & counted])
        theta = trace.controller_state.get("theta_hat")
        if theta is not None:
            self._estimated = True
            self._theta.add(t, theta[rows])
            self._true.add(t, trace.true_parameters_t()[rows])
            if self.confidence is not None:
                self.confidence.on_chunk(trace, start, stop)
        if self.run_window_s is not None:
            self._whole_run(t, eps_c_m, trace.e_m[rows], trace.u_v[rows], counted)

    def _whole_run(
        self, t: np.ndarray, eps_c_m: np.ndarray, e_m: np.ndarray, u_v: np.ndarray, counted: np.ndarray
    ) -> None:
        if t.size == 0:
            return
        self._max_abs_u_v = np.maximum(self._max_abs_u_v, np.abs(u_v).max(axis=0))
        a, b = self.run_window_s
        inside = (t >= a) & (t < b) & counted
        eps_um = eps_c_m * 1e6
        if inside.any():
            sq = np.column_stack([eps_um[inside], e_m[inside] * 1e6]) ** 2
            self._run_sq = carried_sum(self._run_sq, sq)
            self._run_count += int(np.count_nonzero(inside))
            self._run_max_um = max(self._run_max_um, float(np.abs(eps_um[inside]).max()))
        if self.periods_s is None:
            return
        start, period = self.periods_s
        after = t >= start
        index = np.floor((t[after] - start) / period).astype(np.int64)
        sq = (eps_um[after] ** 2)[:, None]
        bounds = np.flatnonzero(np.diff(index)) + 1
        for seg_index, seg in zip(np.split(index, bounds), np.split(sq, bounds), strict=True):
            if seg_index.size == 0:
                continue
            k = int(seg_index[0])
            while len(self._period_sq) <= k:
                self._period_sq.append(np.zeros(1))
                self._period_count.append(0)
            self._period_sq[k] = carried_sum(self._period_sq[k], seg)
            self._period_count[k] += seg_index.size

    def on_end(self, trace: Trace) -> None:
        pass

    def contour(self) -> ContourMetrics:
        eps = np.concatenate(self._eps_c) if self._eps_c else np.zeros(0)
        if eps.size == 0:
            raise ValueError(f"window {self.contour_window_s} s holds no sample of the run")
        return contour_metrics_of(eps, self.contour_window_s)

    def estimates(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(mean theta^, mean true theta) over the estimate window, or None if the controller logs no theta_hat."""
        if not self._estimated:
            return None
        return self._theta.mean(), self._true.mean()

    def whole_run(self) -> WholeRunMetrics | None:
        """The whole run's figures (None without ``run_window_s`` or when no sample fell in it)."""
        if self.run_window_s is None or self._run_count == 0:
            return None
        rms = np.sqrt(self._run_sq / self._run_count)
        start, period = self.periods_s if self.periods_s is not None else (self.run_window_s[0], 0.0)
        per_period = tuple(
            float(np.sqrt(sq[0] / n)) for sq, n in zip(self._period_sq, self._period_count, strict=True) if n
        )
        return WholeRunMetrics(
            window_s=self.run_window_s,
            contour_rms_um=float(rms[0]),
            contour_max_um=self._run_max_um,
            axial_rms_um=(float(rms[1]), float(rms[2])),
            command_window_s=(0.0, self.run_window_s[1]),
            max_abs_command_v=(float(self._max_abs_u_v[0]), float(self._max_abs_u_v[1])),
            periods_start_s=float(start),
            period_s=float(period),
            period_rms_um=per_period,
        )


def error_pct(estimate: float, true: float) -> float | None:
    """100 (estimate - true) / true; None where the true value is 0 (dN)."""
    return None if true == 0.0 else float(100.0 * (estimate - true) / true)


def estimate_errors_pct(estimate: np.ndarray, true_theta: np.ndarray) -> dict[str, float | None]:
    """:func:`error_pct` of each parameter, by name."""
    return {name: error_pct(est, tru) for name, est, tru in zip(THETA_NAMES, estimate, true_theta, strict=True)}


def axial_rms_um(trace: Trace, window_s: tuple[float, float]) -> np.ndarray:
    """rms of each axis's tracking error e = q - q_d over the window, micrometres (X, Y)."""
    e = trace.e_m[window_mask(trace.t_s, window_s)] * 1e6
    return np.sqrt(np.mean(e**2, axis=0))


def max_abs_command_v(trace: Trace) -> np.ndarray:
    """The largest |u| of the recorded (clipped) command over the whole run, per axis (X, Y), volts.

    (The fraction of samples at the DAC limit is :class:`gantry_twin.loop.events.TravelWatch`'s ``saturation``.)
    """
    return np.abs(trace.u_v[: trace.filled]).max(axis=0)
