"""Goals normalised as systune's (docs/tune.md): f = worst / limit over a goal's runs, f <= 1 met; and the runs
of one trial on a worker, the nominal plant first, stopped early when a hard goal already fails there.

Runs here in the worker and in the driver alike: plain data in (resolved
scenarios, :class:`Check`), plain data out (:class:`TrialRuns`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

#: A goal's f when one of its runs failed (diverged, raised): far beyond any bound, finite for the optimiser.
F_FAILED = 1.0e6


@dataclass(frozen=True)
class Check:
    """One goal as the trial judges it: its metric, soft or hard, its limit (absolute: a relative limit already
    multiplied by the baseline's worst) and the indices of the runs (cases) it is judged on."""

    name: str
    metric: str
    kind: str
    limit: float
    cases: tuple[int, ...]


def normalised(value: float, limit: float) -> float:
    """f of one value: value / limit, or 1 + value for a limit of 0 (met only at 0); F_FAILED for a failed run."""
    if value is None or not math.isfinite(value):
        return F_FAILED
    f = value / limit if limit > 0 else 1.0 + value
    return min(f, F_FAILED)


def goal_values(checks: list[Check], metrics: list[dict[str, float] | None]) -> list[float | None]:
    """Each goal's f over those of its runs that ran (metrics[i] None: case i not run); None if none ran."""
    out: list[float | None] = []
    for check in checks:
        ran = [metrics[i] for i in check.cases if i < len(metrics) and metrics[i] is not None]
        out.append(max((normalised(m[check.metric], check.limit) for m in ran), default=None))
    return out


def run_metrics(resolved: dict[str, Any], source: str) -> dict[str, float]:
    """The goal metrics of one run (:data:`gantry_twin.tune.spec.METRICS`), from the run's RunSummary and trace;
    a run that raises has every metric infinite and ``error`` set."""
    from gantry_twin.run import execute, summarise
    from gantry_twin.scenario import build, validate_data
    from gantry_twin.sweep.engine import warm_up

    scenario = validate_data(resolved, source)
    built = build(scenario, source)
    warm_up(scenario, source)
    started = time.perf_counter()
    try:
        trace = execute(built)
    except Exception as exc:  # the design made the run fail (diverged): the goals say so, the study goes on
        bad = {name: math.inf for name in ("contour_rms_um", "contour_max_um", "saturated_fraction", "du_rms_v")}
        message = str(exc).splitlines()[0] if str(exc) else ""
        return {**bad, "end_stop_contacts": math.inf, "alarms": math.inf, "error": f"{type(exc).__name__}: {message}"}
    summary = summarise(built, trace)
    lo, hi = scenario.metric_window_s
    inside = (trace.t_s >= lo) & (trace.t_s < hi)
    du = np.diff(trace.u_v[inside], axis=0)
    saturation = summary.saturation or {}
    return {
        "contour_rms_um": float(summary.contour_error_um.rms),
        "contour_max_um": float(summary.contour_error_um.max),
        "saturated_fraction": max((float(s.fraction) for s in saturation.values()), default=0.0),
        "end_stop_contacts": float(sum((summary.end_stop_contacts or {}).values())),
        "du_rms_v": float(np.sqrt(np.mean(du**2, axis=0)).max()) if du.size else 0.0,
        "alarms": float(len(summary.health.alarms)) if summary.health is not None else 0.0,
        "wall_time_s": time.perf_counter() - started,
    }


@dataclass
class TrialRuns:
    """What a worker sends back for one trial: each case's metrics (None: not run) and whether it stopped early."""

    metrics: list[dict[str, float] | None]
    pruned: bool
    wall_time_s: float


def run_trial(cases: list[dict[str, Any]], source: str, checks: list[Check], nominal: int) -> TrialRuns:
    """Run a trial's cases in order; after the first ``nominal`` ones (the nominal plant's runs), stop if a hard
    goal is already broken there (the worst case over the ensemble can only be worse)."""
    started = time.perf_counter()
    metrics: list[dict[str, float] | None] = [None] * len(cases)
    hard = [c for c in checks if c.kind == "hard"]
    for i, resolved in enumerate(cases):
        metrics[i] = run_metrics(resolved, source)
        if i + 1 == nominal and i + 1 < len(cases):
            if any(f is not None and f > 1.0 for f in goal_values(hard, metrics)):
                return TrialRuns(metrics, True, time.perf_counter() - started)
    return TrialRuns(metrics, False, time.perf_counter() - started)
