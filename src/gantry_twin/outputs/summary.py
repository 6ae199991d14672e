"""summary.json, the run's output contract: built from what a run's observers gathered, canonical JSON text.

A pure function of the resolved scenario and the code, so the same scenario
run twice gives the same bytes; the wall-clock time lives in
``run_info.json`` beside it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import ValidationError

from gantry_twin.inputs import InputFileError, read_input_file
from gantry_twin.metrics import RunMetrics, WholeRunMetrics, estimate_errors_pct
from gantry_twin.plant.model import AXES, THETA_NAMES
from gantry_twin.settings import Model, describe, shorten

#: Version of the summary.json layout; bumped on any incompatible change.
SUMMARY_SCHEMA_VERSION = 1

Window = tuple[float, float]
PerAxis = dict[str, float]


class ContourError(Model):
    """eps_c over the scenario's metric window, um."""

    rms: float
    max: float
    window_s: Window
    paper_window: bool | None = None  # window_s is the paper's second period [T, 2T] (None: not recorded)


class WholeRunContour(Model):
    rms: float
    max: float


class WholeRun(Model):
    """From the start of the metric window to the end of the run: eps_c, axial rms, largest |u|."""

    window_s: Window
    contour_error_um: WholeRunContour
    axial_error_rms_um: PerAxis
    command_window_s: Window
    max_abs_command_v: PerAxis


class PerPeriod(Model):
    start_s: float
    period_s: float
    rms: list[float]


class Estimate(Model):
    """One parameter's estimate (volt units), its true value, the error, and the trust verdict (docs/cli.md)."""

    estimate: float
    true: float | None = None
    error_pct: float | None = None
    trustworthy: bool | None = None
    why: str | None = None
    excitation_v: float | None = None
    bias_bound_pct: float | None = None
    fit_gap_pct: float | None = None

    @property
    def distrust(self) -> str:
        """``not trusted: why`` when the run's own signals cannot vouch for the estimate, else empty: the one
        phrase the printed summary, the plots, compare, the report and the dashboard mark it with."""
        return f"not trusted: {self.why}" if self.trustworthy is False else ""


class Confidence(Model):
    """The sums the trust verdicts were judged from (:func:`gantry_twin.health.confidence.judge`)."""

    span_s: Window
    seconds: float
    window_sliding_fraction: list[float]
    information: list[Any]
    friction_moment: list[Any]
    quantisation_noise: list[Any]
    scale: list[float]


class AlarmRecord(Model):
    """An alarm as :class:`gantry_twin.health.monitor.Alarm` holds it."""

    parameter: str
    time_s: float
    direction: str
    change_pct: float | None
    change: float
    unit: str
    estimate: float
    baseline: float
    cleared_s: float | None
    #: Seconds since the monitor's first sample (a shadow's: since it started following); absent in older files.
    since_start_s: float | None = None


class AxisExcitation(Model):
    level_v_final: float | None
    level_v_min: float | None
    excited_fraction: float


class Health(Model):
    """The health monitor's verdict (docs/health.md)."""

    alarms: list[AlarmRecord]
    #: The parameters judged at least once (ok, drifting or alarm); empty: the monitor judged nothing.
    judged: list[str] | None = None
    status: dict[str, str]
    time_in_status_s: dict[str, dict[str, float]]
    excitation: dict[str, AxisExcitation]
    baseline: dict[str, str | float] | None = None


class FailureRecord(Model):
    time_s: float | None
    step: int | None
    error: str


class EndStopEvent(Model):
    t_s: float
    kind: str
    axis: str
    end_m: float
    position_m: float
    left_s: float | None


class Saturation(Model):
    fraction: float
    limit_v: Window


class PartBlock(Model):
    line: int
    max_um: float
    rms_um: float
    time_s: float
    feed_achieved_m_s: float
    feed_programmed_m_s: float


class PartCorner(Model):
    line: int
    kind: str
    point_m: Window
    turn_rad: float
    max_um: float
    speed_m_s: float
    time_s: float


class PartErrorRecord(Model):
    """A part program's error: the distance of the actual position to the programmed lines and arcs
    (docs/gcode.md): totals, and the worst blocks and corners (at most 50 of each)."""

    max_um: float
    rms_um: float
    cycle_time_s: float
    feed_achieved_m_s: float
    blocks: int
    corners: int
    worst_blocks: list[PartBlock]
    worst_corners: list[PartCorner]
    #: The program's (print, ...) (debug, ...) (msg, ...) lines, the words dropped and the G1 lines merged (G64 Q).
    messages: list[str] = []
    dropped: dict[str, int] = {}
    merged: int = 0


class LiveLink(Model):
    """``monitor --opcua``: what came over the link (docs/live-link.md)."""

    endpoint: str
    mode: Literal["blocks", "scalars"]
    sample_period_s: float | None
    samples: int
    first_index: int | None
    #: The machine's time of the first sample followed: the zero of the monitor's windows (docs/live-link.md).
    first_t_s: float | None = None
    covered_s: float
    gaps: int
    missing_samples: int
    invalid_samples: int
    reconnects: int
    ended_by: str
    residual_windows: int
    #: The most items (blocks, scalar values) received and not yet estimated at once: stays small when the
    #: shadow keeps up with the machine.
    backlog_max_items: int
    #: The items waiting, read once a second of wall time.
    backlog_items_per_s: list[int] | None = None
    residual_rms_um: dict[str, float] | None = None
    residual_max_um: dict[str, float] | None = None


class RunSummary(Model):
    """summary.json: the one type every producer writes and every consumer reads (docs/cli.md, "summary.json").

    A run of a scenario names ``scenario``; ``monitor --log`` names ``log``.
    Sections a run does not have are absent (never null): a failed run has
    ``failure`` and no contour error; a controller without estimates has no
    ``estimates``; a run without the monitor has no ``health``.
    """

    schema_version: Literal[SUMMARY_SCHEMA_VERSION]  # type: ignore[valid-type]
    scenario: str | None = None
    log: str | None = None
    plant: str | None = None
    controller: str
    overrides: list[str] | None = None
    controller_option: str | None = None
    duration_s: float
    sample_period_s: float
    steps: int
    status: Literal["ok", "failed", "stopped"]
    failure: FailureRecord | None = None
    contour_error_um: ContourError | None = None
    whole_run: WholeRun | None = None
    contour_error_per_period_um: PerPeriod | None = None
    estimates_window_s: Window | None = None
    estimates: dict[str, Estimate] | None = None
    confidence: Confidence | None = None
    health: Health | None = None
    events: list[EndStopEvent] | None = None
    end_stop_contacts: dict[str, int] | None = None
    saturation: dict[str, Saturation] | None = None
    part_error: PartErrorRecord | None = None
    live: LiveLink | None = None

    @property
    def failed(self) -> bool:
        return self.status != "ok"

    def as_dict(self) -> dict[str, Any]:
        """The JSON-ready content, exactly the keys that were given (what :func:`summary_json` writes)."""
        return self.model_dump(mode="json", exclude_unset=True)

    @classmethod
    def read(cls, path: str | Path) -> RunSummary:
        """A summary.json read back through the type; :class:`SummaryError` when it is not a regular file, too
        large, not JSON, or a key is unknown, missing or of the wrong type (the error names the field)."""
        try:
            text = read_input_file(path, "a run's summary.json")
        except InputFileError as exc:
            raise SummaryError(path, str(exc)) from None
        try:
            summary = cls.model_validate_json(text)
        except ValidationError as exc:
            error = exc.errors()[0]
            if error["type"] == "json_invalid":
                why = shorten(str(error.get("ctx", {}).get("error", "")) or error["msg"], 80)
                raise SummaryError(path, f"is not a run's summary.json (invalid JSON: {why})") from None
            field, message = describe(error)
            raise SummaryError(
                path, f"{field}: {message}" if field else f"is not a run's summary.json ({message})"
            ) from None
        except RecursionError:
            raise SummaryError(path, "is nested too deeply to be a run's summary.json") from None
        where = _not_finite(summary.as_dict())
        if where is not None:  # JSON has no NaN or Infinity; a summary.json written here never holds them
            raise SummaryError(path, f"{where}: NaN or Infinity is not a number a run's summary.json holds")
        return summary


def _not_finite(data: Any, where: str = "") -> str | None:
    """The path (``a.b[2]``) of the first NaN or infinite number in JSON-like ``data``, else None."""
    if isinstance(data, float) and not math.isfinite(data):
        return where or "(top level)"
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list) else ()
    for key, value in items:
        found = _not_finite(value, f"{where}[{key}]" if isinstance(key, int) else f"{where}.{key}".lstrip("."))
        if found is not None:
            return found
    return None


class SummaryError(ValueError):
    """A summary.json that cannot be read as :class:`RunSummary`: the file and one line saying what is wrong."""

    def __init__(self, path: str | Path, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path, self.reason = Path(path), reason


@dataclass(frozen=True)
class Failure:
    """Why a run stopped before its end: at time_s, sample ``step`` (None if before the first), the error text;
    ``stopped``: a stop signal ended it (summary.json's status ``stopped``), not a fault (``failed``)."""

    time_s: float | None
    step: int | None
    error: str
    stopped: bool = False


def run_summary(
    scenario: Any,
    controller_name: str,
    sample_period_s: float,
    steps: int,
    metrics: RunMetrics,
    health: Any = None,
    failure: Failure | None = None,
    overrides: Sequence[str] = (),
    controller_option: str | None = None,
    travel: dict[str, Any] | None = None,
    part: dict[str, Any] | None = None,
) -> RunSummary:
    """summary.json of a run of ``scenario`` (a :class:`gantry_twin.scenario.Scenario`) from what the run's
    observers gathered; ``failure``: the run stopped early (status failed,
    no contour error or estimates: they judge a whole run). ``overrides``, ``controller_option``: the command
    line's ``--set KEY=VALUE`` and ``--controller`` (already in the resolved scenario; kept to say how it was made)."""
    out: dict[str, Any] = {
        "schema_version": SUMMARY_SCHEMA_VERSION,
        "scenario": scenario.name,
        "plant": scenario.plant.label,
        "controller": controller_name,
        "overrides": list(overrides),
        "controller_option": controller_option,
        "duration_s": scenario.duration_s,
        "sample_period_s": sample_period_s,
        "steps": int(steps),
        "status": "ok" if failure is None else "stopped" if failure.stopped else "failed",
    }
    if failure is not None:
        out["failure"] = {"time_s": failure.time_s, "step": failure.step, "error": failure.error}
    else:
        contour = metrics.contour()
        out["contour_error_um"] = {
            "rms": contour.rms_um,
            "max": contour.max_um,
            "window_s": list(contour.window_s),
            "paper_window": scenario.metric_window_is_papers,
        }
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
    out.update(travel or {})  # events, end_stop_contacts, saturation (gantry_twin.loop.events.TravelWatch.summary)
    if part is not None and failure is None:
        out["part_error"] = part
    return RunSummary.model_validate(out)


def whole_run_summary(whole: WholeRunMetrics) -> dict[str, Any]:
    """The ``whole_run`` and ``contour_error_per_period_um`` sections (docs/cli.md); the latter only for a run
    with periods (not a part program's)."""
    out: dict[str, Any] = {
        "whole_run": {
            "window_s": list(whole.window_s),
            "contour_error_um": {"rms": whole.contour_rms_um, "max": whole.contour_max_um},
            "axial_error_rms_um": dict(zip(AXES, whole.axial_rms_um, strict=True)),
            "command_window_s": list(whole.command_window_s),
            "max_abs_command_v": dict(zip(AXES, whole.max_abs_command_v, strict=True)),
        },
    }
    if whole.period_s > 0.0:
        out["contour_error_per_period_um"] = {
            "start_s": whole.periods_start_s,
            "period_s": whole.period_s,
            "rms": list(whole.period_rms_um),
        }
    return out


def health_summary(report: Any) -> dict[str, Any]:
    """The ``health`` section: alarms, status per parameter, excitation per axis (docs/health.md), of a monitor's
    :class:`~gantry_twin.health.monitor.MonitorReport` or of the :class:`~gantry_twin.health.tally.MonitorTally`
    of its periods (``monitor --log``, a report at a time)."""
    from gantry_twin.health.tally import MonitorTally

    tally = report if isinstance(report, MonitorTally) else MonitorTally.of(report)
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
            "since_start_s": a.since_start_s,
        }
        for a in tally.alarms
    ]
    excitation = {}
    for i, axis in enumerate(AXES):
        seen = tally.level_final is not None
        excitation[axis] = {
            "level_v_final": float(tally.level_final[i]) if seen else None,
            "level_v_min": float(tally.level_min[i]) if seen else None,
            "excited_fraction": tally.excited_fraction(i),
        }
    out: dict[str, Any] = {
        "alarms": alarms,
        "judged": tally.judged(),
        "status": tally.final_status(),
        "time_in_status_s": tally.time_in_status_s(tally.period_s),
        "excitation": excitation,
    }
    if tally.baseline is not None:
        out["baseline"] = {"source": tally.baseline.source, **tally.baseline.as_dict()}
    return out


def summary_json(summary: RunSummary) -> str:
    """Canonical JSON text: the type's key order, shortest round-trip floats, newline at the end."""
    return json.dumps(summary.as_dict(), indent=2, allow_nan=False) + "\n"


def log_summary(log: Any, tally: Any, live: dict[str, Any] | None = None) -> RunSummary:
    """summary.json of ``monitor --log``: the log (:class:`gantry_twin.sysid.logs.LogInfo`), the mean estimates
    over the tally's window and the ``health`` section, from the
    :class:`~gantry_twin.health.tally.MonitorTally` of the monitor's periods."""
    data: dict[str, Any] = {
        "schema_version": SUMMARY_SCHEMA_VERSION,
        "log": str(Path(log.path)),
        "controller": "diarc",
        "duration_s": log.duration_s,
        "sample_period_s": log.sample_period_s,
        "steps": log.samples,
        "status": "ok",
    }
    mean = tally.estimates_mean()
    if mean is not None:
        data["estimates_window_s"] = list(tally.estimate_window_s)
        data["estimates"] = {name: {"estimate": float(v)} for name, v in zip(THETA_NAMES, mean, strict=True)}
    data["health"] = health_summary(tally)
    if live is not None:
        data["live"], data["log"] = live, live["endpoint"]  # an endpoint is no path
    return RunSummary.model_validate(data)
