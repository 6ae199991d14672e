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
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from gantry_twin.controllers import DIARC
from gantry_twin.controllers.base import U_MAX_V, Measurement, RunContext
from gantry_twin.health.estimator_replay import estimator_replay
from gantry_twin.health.monitor import MachineMonitor, MonitorReport
from gantry_twin.outputs.summary import SUMMARY_SCHEMA_VERSION, health_summary
from gantry_twin.plant import THETA_NAMES
from gantry_twin.sysid.logs import Log, read_log
from gantry_twin.trace import Trace

#: summary.json's estimates: the mean over the log's last ESTIMATE_WINDOW_S (at most half the log), s.
ESTIMATE_WINDOW_S = 10.0


def estimates(controller: DIARC, log: Log) -> np.ndarray:
    """theta^ (n, 8) of DIARC's estimator (its gains and estimator settings) over the log, volt units."""
    ts = log.sample_period_s
    dq = np.empty_like(log.q_m)
    dq[1:] = np.diff(log.q_m, axis=0) / ts
    dq[0] = dq[1]
    controller.reset(RunContext(ts, np.array(U_MAX_V), Measurement(float(log.t_s[0]), log.q_m[0], dq[0])))
    params, state = controller.kernel_arguments()
    out = np.empty((log.samples, 8))
    estimator_replay(params, state.theta, state.estimator, np.ascontiguousarray(log.q_m), dq, log.u_v, out)
    return out


def log_trace(log: Log, theta_hat: np.ndarray) -> Trace:
    """A trace of what the log holds (no true positions, no contour errors) with DIARC's estimates."""
    n = log.samples
    nan2, nan = np.full((n, 2), np.nan), np.full(n, np.nan)
    q_d = log.q_d_m if log.q_d_m is not None else nan2
    return Trace(
        t_s=log.t_s,
        q_m=nan2,
        q_meas_m=log.q_m,
        q_d_m=q_d,
        e_m=nan2,
        eps_n_m=nan,
        eps_c_m=nan,
        u_v=log.u_v,
        disturbance_v=np.zeros((n, 2)),
        true_theta=np.full(8, np.nan),
        controller_state={"theta_hat": theta_hat},
        filled=n,
        timestep_s=log.sample_period_s,
    )


def monitor_log(log: Log, controller: DIARC, monitor: MachineMonitor) -> MonitorReport:
    """DIARC's estimator and the health monitor over a log."""
    trace = log_trace(log, estimates(controller, log))
    monitor.on_start(None, trace)
    monitor.on_chunk(trace, 0, trace.filled)
    monitor.on_end(trace)
    return monitor.report()


def log_summary(log: Log, report: MonitorReport, estimate_window_s: tuple[float, float]) -> dict[str, Any]:
    """summary.json of ``monitor --log``: the log, the mean estimates over the window, the ``health`` section."""
    theta = report.estimate
    t = report.t_s
    lo, hi = estimate_window_s
    inside = (t >= lo) & (t <= hi) if theta is not None else np.zeros(0, dtype=bool)
    data: dict[str, Any] = {
        "schema_version": SUMMARY_SCHEMA_VERSION,
        "log": str(Path(log.path)),
        "controller": "diarc",
        "duration_s": log.duration_s,
        "sample_period_s": log.sample_period_s,
        "steps": log.samples,
        "status": "ok",
    }
    if theta is not None and inside.any():
        mean = theta[inside].mean(axis=0)
        data["estimates_window_s"] = [lo, hi]
        data["estimates"] = {name: {"estimate": float(v)} for name, v in zip(THETA_NAMES, mean, strict=True)}
    data["health"] = health_summary(report)
    return data


def command(args: Any, scenario_path: Path | None, out: Path) -> dict[str, Any]:
    """``gantry-twin monitor --log LOG [SCENARIO] [--baseline SUMMARY]``: run it, write out/summary.json, return it.

    The scenario (default: every field's default) gives DIARC's gains and
    estimator and the monitor's settings; ``--baseline`` a commissioning
    run's summary.json (as ``monitor.baseline_summary``). Raises LogError,
    ScenarioError or ValueError (bad input: exit 2).
    """
    from gantry_twin.controllers import create
    from gantry_twin.outputs.files import atomic_write_text
    from gantry_twin.outputs.summary import summary_json
    from gantry_twin.scenario import apply_overrides, controller_options, load_scenario, make_monitor, validate_data

    overrides = ["monitor.enable=true", *args.overrides]
    if args.baseline is not None:
        overrides.append(f"monitor.baseline_summary={json.dumps(str(Path(args.baseline).resolve()))}")
    if scenario_path is not None:
        source = str(scenario_path)
        scenario = load_scenario(scenario_path, overrides, args.controller)
    else:
        source = "<defaults>"
        data = {"controller": {"name": args.controller}} if args.controller else {}
        scenario = validate_data(apply_overrides(data, overrides, source), source, "log")
    controller = create(scenario.controller.name, **controller_options(scenario, source))
    if not isinstance(controller, DIARC):
        raise ValueError(
            f"monitor --log runs DIARC's estimator; the scenario's controller is {scenario.controller.name}"
        )
    monitor = make_monitor(scenario, controller, source)
    log = read_log(args.log)
    report = monitor_log(log, controller, monitor)
    end = float(log.t_s[-1])
    data = log_summary(log, report, (end - min(ESTIMATE_WINDOW_S, 0.5 * log.duration_s), end))
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "summary.json", summary_json(data))
    return data
