"""summary.json, the run's output contract: built from what a run's observers gathered, canonical JSON text.

A pure function of the resolved scenario and the code, so the same scenario
run twice gives the same bytes; the wall-clock time lives in
``run_info.json`` beside it.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from gantry_twin.metrics import RunMetrics, WholeRunMetrics, estimate_errors_pct
from gantry_twin.plant import AXES, THETA_NAMES
from gantry_twin.scenario import Scenario

#: Version of the summary.json layout; bumped on any incompatible change.
SUMMARY_SCHEMA_VERSION = 1


@dataclass(frozen=True)
class Failure:
    """Why a run stopped before its end: at time_s, sample ``step`` (None if before the first), the error text."""

    time_s: float | None
    step: int | None
    error: str


def run_summary(
    scenario: Scenario,
    controller_name: str,
    sample_period_s: float,
    steps: int,
    metrics: RunMetrics,
    health: Any = None,
    failure: Failure | None = None,
    overrides: Sequence[str] = (),
    controller_option: str | None = None,
) -> dict[str, Any]:
    """:func:`summary` from what the run's observers gathered; ``failure``: the run stopped early (status failed,
    no contour error or estimates: they judge a whole run). ``overrides``, ``controller_option``: the command
    line's ``--set KEY=VALUE`` and ``--controller`` (already in the resolved scenario; kept to say how it was made)."""
    out: dict[str, Any] = {
        "schema_version": SUMMARY_SCHEMA_VERSION,
        "scenario": scenario.name,
        "controller": controller_name,
        "overrides": list(overrides),
        "controller_option": controller_option,
        "duration_s": scenario.duration_s,
        "sample_period_s": sample_period_s,
        "steps": int(steps),
        "status": "ok" if failure is None else "failed",
    }
    if failure is not None:
        out["failure"] = {"time_s": failure.time_s, "step": failure.step, "error": failure.error}
    else:
        contour = metrics.contour()
        out["contour_error_um"] = {"rms": contour.rms_um, "max": contour.max_um, "window_s": list(contour.window_s)}
        whole = metrics.whole_run()
        if whole is not None:
            out.update(whole_run_summary(whole))
        estimates = metrics.estimates()
        if estimates is not None and estimates[0].shape == (len(THETA_NAMES),):  # a plug-in may log another
            estimate, true = estimates
            errors = estimate_errors_pct(estimate, true)
            out["estimates_window_s"] = list(scenario.estimate_window_s)
            out["estimates"] = {
                name: {"estimate": float(est), "true": float(tru), "error_pct": errors[name]}
                for name, est, tru in zip(THETA_NAMES, estimate, true, strict=True)
            }
            if metrics.confidence is not None:  # trustworthy, why, excitation_v, bias_bound_pct (docs/cli.md)
                for name, verdict in metrics.confidence.verdicts(estimate).items():
                    out["estimates"][name].update(verdict)
                out["confidence"] = metrics.confidence.statistics()
    if health is not None:
        out["health"] = health_summary(health)
    return out


def whole_run_summary(whole: WholeRunMetrics) -> dict[str, Any]:
    """The ``whole_run`` and ``contour_error_per_period_um`` sections (docs/cli.md)."""
    return {
        "whole_run": {
            "window_s": list(whole.window_s),
            "contour_error_um": {"rms": whole.contour_rms_um, "max": whole.contour_max_um},
            "axial_error_rms_um": dict(zip(AXES, whole.axial_rms_um, strict=True)),
            "command_window_s": list(whole.command_window_s),
            "max_abs_command_v": dict(zip(AXES, whole.max_abs_command_v, strict=True)),
        },
        "contour_error_per_period_um": {
            "start_s": whole.periods_start_s,
            "period_s": whole.period_s,
            "rms": list(whole.period_rms_um),
        },
    }


def health_summary(report: Any) -> dict[str, Any]:
    """The ``health`` section: alarms, status per parameter, excitation per axis (docs/health.md)."""
    period = float(report.t_s[1] - report.t_s[0]) if report.t_s.size > 1 else 0.0
    alarms = [
        {
            "parameter": a.parameter,
            "time_s": a.time_s,
            "direction": a.direction,
            "change_pct": a.change_pct,
            "change": a.change,
            "unit": a.unit,
            "estimate": a.estimate,
            "baseline": a.baseline,
            "cleared_s": a.cleared_s,
        }
        for a in report.alarms
    ]
    excitation = {}
    for i, axis in enumerate(AXES):
        level = report.level_v[:, i] if report.level_v.size else np.zeros(0)
        excitation[axis] = {
            "level_v_final": float(level[-1]) if level.size else None,
            "level_v_min": float(level.min()) if level.size else None,
            "excited_fraction": float(report.excited[:, [j for j in range(8) if j % 2 == i]].all(axis=1).mean())
            if level.size
            else 0.0,
        }
    out: dict[str, Any] = {
        "alarms": alarms,
        "status": report.final_status(),
        "time_in_status_s": report.time_in_status_s(period),
        "excitation": excitation,
    }
    if report.baseline is not None:
        out["baseline"] = {"source": report.baseline.source, **report.baseline.as_dict()}
    return out


def summary_json(data: dict[str, Any]) -> str:
    """Canonical JSON text: fixed key order, shortest round-trip floats, newline at the end."""
    return json.dumps(data, indent=2, allow_nan=False) + "\n"
