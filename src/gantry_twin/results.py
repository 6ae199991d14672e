"""What a run leaves behind: summary.json, the trace as Parquet, atomic writes.

``summary.json`` is a stable contract (docs/cli.md): a pure function of the
resolved scenario and the code, so the same scenario run twice gives the
same bytes. The wall-clock time is the only thing that differs between two
runs, so it lives in ``run_info.json`` beside it.

Every file is written atomically: into a temporary file in the same
directory, flushed and fsync'ed, then renamed over the final name
(``os.replace``). A crash leaves either the old file, the new file, or a
hidden ``.<name>.*.part`` file, never a half-written file under the final
name.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from gantry_twin.metrics import contour_metrics, estimate_errors_pct, steady_estimates, steady_true_parameters
from gantry_twin.plant import AXES, THETA_NAMES
from gantry_twin.scenario import Scenario
from gantry_twin.trace import Trace

#: Version of the summary.json layout; bumped on any incompatible change.
SUMMARY_SCHEMA_VERSION = 1


def atomic_write(path: Path, write: Callable[[IO[bytes]], None]) -> None:
    """Write a file via temp file + fsync + os.replace; on error no file appears."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _fsync_dir(path.parent)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write(path, lambda fh: fh.write(text.encode("utf-8")))


def _fsync_dir(directory: Path) -> None:
    """Make the rename durable (POSIX; a no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def summary(scenario: Scenario, trace: Trace, controller_name: str, health: Any = None) -> dict[str, Any]:
    """The summary.json contract (see docs/cli.md); deterministic for a given scenario.

    health: the run's :class:`gantry_twin.monitor.MonitorReport` (a ``health``
    section is added only when given). Estimates are judged against the mean
    true theta over the same window (it moves when the scenario has changes).
    """
    metrics = contour_metrics(trace, scenario.metric_window_s)
    out: dict[str, Any] = {
        "schema_version": SUMMARY_SCHEMA_VERSION,
        "scenario": scenario.name,
        "controller": controller_name,
        "duration_s": scenario.duration_s,
        "sample_period_s": trace.sample_period_s,
        "steps": int(trace.filled),
        "contour_error_um": {"rms": metrics.rms_um, "max": metrics.max_um, "window_s": list(metrics.window_s)},
    }
    estimate = steady_estimates(trace, scenario.estimate_window_s)
    if estimate is not None and estimate.shape == (len(THETA_NAMES),):  # a plug-in may log another theta_hat
        true = steady_true_parameters(trace, scenario.estimate_window_s)
        errors = estimate_errors_pct(estimate, true)
        out["estimates_window_s"] = list(scenario.estimate_window_s)
        out["estimates"] = {
            name: {"estimate": float(est), "true": float(tru), "error_pct": errors[name]}
            for name, est, tru in zip(THETA_NAMES, estimate, true, strict=True)
        }
    if health is not None:
        out["health"] = health_summary(health)
    return out


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


def _columns(name: str, values: np.ndarray) -> dict[str, np.ndarray]:
    """Split an (N,), (N, 2) or (N, 8) series into scalar columns."""
    if values.ndim == 1:
        return {name: values}
    flat = values.reshape(values.shape[0], -1)
    width = flat.shape[1]
    if width == 2:
        suffixes: tuple[str, ...] = AXES
    elif width == len(THETA_NAMES):
        suffixes = THETA_NAMES
    else:
        suffixes = tuple(str(i) for i in range(width))
    return {f"{name}_{s}": flat[:, i] for i, s in enumerate(suffixes)}


def trace_table(trace: Trace, stride: int = 1) -> pa.Table:
    """The trace as one column per scalar series (SI units and volts), every ``stride``-th sample.

    Columns: t_s; x_m, y_m (true position); x_meas_m, y_meas_m (encoder);
    x_d_m, y_d_m (desired); e_x_m, e_y_m; eps_n_m, eps_c_m; u_x_v, u_y_v
    (command); d_x_v, d_y_v (input disturbance); then the controller's logged
    state, e.g. theta_hat_M1 ... theta_hat_dN2, dc_hat_x, dc_hat_y.
    The true parameters at t = 0 are in the schema metadata (``true_theta``,
    JSON); when the scenario changes the plant they are also columns,
    true_theta_M1 ... true_theta_dN2, volt units.
    """
    n = trace.filled
    rows = slice(0, n, stride)
    cols: dict[str, np.ndarray] = {"t_s": trace.t_s[rows]}
    cols.update({"x_m": trace.q_m[rows, 0], "y_m": trace.q_m[rows, 1]})
    cols.update({"x_meas_m": trace.q_meas_m[rows, 0], "y_meas_m": trace.q_meas_m[rows, 1]})
    cols.update({"x_d_m": trace.q_d_m[rows, 0], "y_d_m": trace.q_d_m[rows, 1]})
    cols.update({"e_x_m": trace.e_m[rows, 0], "e_y_m": trace.e_m[rows, 1]})
    cols.update({"eps_n_m": trace.eps_n_m[rows], "eps_c_m": trace.eps_c_m[rows]})
    cols.update({"u_x_v": trace.u_v[rows, 0], "u_y_v": trace.u_v[rows, 1]})
    cols.update({"d_x_v": trace.disturbance_v[rows, 0], "d_y_v": trace.disturbance_v[rows, 1]})
    for key in sorted(trace.controller_state):
        cols.update(_columns(key, trace.controller_state[key][rows]))
    if trace.true_theta_t is not None:  # the plant changed during the run
        cols.update(_columns("true_theta", trace.true_theta_t[rows]))
    meta = {"true_theta": json.dumps(dict(zip(THETA_NAMES, map(float, trace.true_theta), strict=True)))}
    table = pa.table({k: pa.array(np.ascontiguousarray(v, dtype=float)) for k, v in cols.items()})
    return table.replace_schema_metadata({**(table.schema.metadata or {}), **meta})


def write_parquet(path: Path, table: pa.Table) -> None:
    atomic_write(path, lambda fh: pq.write_table(table, fh))
