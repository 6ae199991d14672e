"""The totals of a health monitor's periods, kept a report at a time so that their memory does not grow with
the run or log (``monitor --log`` on a log of any length; docs/health.md, docs/logs.md)."""

from __future__ import annotations

import numpy as np

from gantry_twin.plant.model import THETA_NAMES

#: Status codes of a monitor report's ``status`` and their names (gantry_twin.health.monitor uses them).
STATUS_NAMES: tuple[str, ...] = ("baseline", "not excited", "ok", "drifting", "alarm", "untrustworthy")
BASELINE, NOT_EXCITED, OK, DRIFTING, ALARM, UNTRUSTWORTHY = range(6)


class MonitorTally:
    """The totals of a monitor's periods that summary.json's ``health`` section needs (and the mean estimate
    over a window), added a :class:`MonitorReport` at a time: what ``monitor --log`` keeps of a log of any
    length (:meth:`MachineMonitor.report` with ``clear=True`` after each chunk), memory independent of it."""

    def __init__(self, estimate_window_s: tuple[float, float] | None = None, trailing_s: float = 0.0) -> None:
        self.periods = 0
        self.first_t: list[float] = []  # the first two periods' end times: the monitor's period
        self.level_final: np.ndarray | None = None
        self.level_min = np.full(2, np.inf)
        self.excited_periods = np.zeros(2)  # periods in which all of an axis' parameters were excited
        self.has_status = False
        self.status_periods = np.zeros((8, len(STATUS_NAMES)), dtype=np.int64)
        self.last_status: np.ndarray | None = None
        self.alarms: list = []  # gantry_twin.health.monitor.Alarm
        self.baseline = None  # gantry_twin.health.monitor.Baseline
        self.estimate_window_s = estimate_window_s
        self.estimate_sum = np.zeros(8)
        self.estimate_count = 0
        #: A stream whose end is not known ahead (``monitor --opcua``): the periods' estimates of the last
        #: ``trailing_s`` are kept until :meth:`close_window` names the window.
        self.trailing_s = float(trailing_s)
        self._trailing: list[tuple[np.ndarray, np.ndarray]] = []

    @classmethod
    def of(cls, report) -> MonitorTally:  # a gantry_twin.health.monitor.MonitorReport
        tally = cls()
        tally.add(report)
        return tally

    def add(self, report) -> None:  # a gantry_twin.health.monitor.MonitorReport
        """The periods of ``report`` (the next ones after those added before); its alarms and baseline replace
        those held (a report holds all alarms so far)."""
        m = int(report.t_s.size)
        self.first_t.extend(float(t) for t in report.t_s[: max(0, 2 - len(self.first_t))])
        self.alarms, self.baseline = list(report.alarms), report.baseline
        if report.status is not None:
            self.has_status = True
        if m == 0:
            return
        self.periods += m
        self.level_final = np.asarray(report.level_v[-1], dtype=float)
        self.level_min = np.minimum(self.level_min, report.level_v.min(axis=0))
        for i in range(2):
            self.excited_periods[i] += int(report.excited[:, [j for j in range(8) if j % 2 == i]].all(axis=1).sum())
        if report.status is not None and len(report.status):
            for code in range(len(STATUS_NAMES)):
                self.status_periods[:, code] += (report.status == code).sum(axis=0)
            self.last_status = np.asarray(report.status[-1])
        if report.estimate is not None and self.estimate_window_s is None and self.trailing_s > 0:
            self._trailing.append((np.asarray(report.t_s, dtype=float), np.asarray(report.estimate, dtype=float)))
            newest = float(report.t_s[-1])
            while self._trailing and float(self._trailing[0][0][-1]) < newest - self.trailing_s:
                self._trailing.pop(0)
        if report.estimate is not None and self.estimate_window_s is not None:
            lo, hi = self.estimate_window_s
            inside = (report.t_s >= lo) & (report.t_s <= hi)
            self.estimate_sum += report.estimate[inside].sum(axis=0)
            self.estimate_count += int(inside.sum())

    def close_window(self, window_s: tuple[float, float]) -> None:
        """The estimate window of a stream, once its end is known: the mean of :meth:`estimates_mean` is taken
        over the trailing periods inside it (at most ``trailing_s`` back)."""
        self.estimate_window_s = window_s
        lo, hi = window_s
        for t_s, estimate in self._trailing:
            inside = (t_s >= lo) & (t_s <= hi)
            self.estimate_sum += estimate[inside].sum(axis=0)
            self.estimate_count += int(inside.sum())
        self._trailing = []

    @property
    def period_s(self) -> float:
        return self.first_t[1] - self.first_t[0] if len(self.first_t) > 1 else 0.0

    def judged(self) -> list[str]:
        """The parameters the monitor judged at least once (status ok, drifting or alarm), in theta's order."""
        seen = self.status_periods[:, [OK, DRIFTING, ALARM]].sum(axis=1) > 0
        return [n for n, s in zip(THETA_NAMES, seen, strict=True) if s]

    def final_status(self) -> dict[str, str]:
        """The status of each parameter after the last period."""
        if self.last_status is None:
            return {}
        return {n: STATUS_NAMES[int(c)] for n, c in zip(THETA_NAMES, self.last_status, strict=True)}

    def time_in_status_s(self, period_s: float) -> dict[str, dict[str, float]]:
        """Seconds each parameter spent in each status."""
        if not self.has_status:
            return {}
        return {
            n: {s: float(self.status_periods[j, c] * period_s) for c, s in enumerate(STATUS_NAMES)}
            for j, n in enumerate(THETA_NAMES)
        }

    def excited_fraction(self, axis: int) -> float:
        return float(self.excited_periods[axis] / self.periods) if self.periods else 0.0

    def estimates_mean(self) -> np.ndarray | None:
        """The mean estimate over the periods ending inside ``estimate_window_s``; None if none did."""
        return self.estimate_sum / self.estimate_count if self.estimate_count else None
