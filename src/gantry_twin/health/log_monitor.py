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

import numpy as np

from gantry_twin.controllers import DIARC
from gantry_twin.controllers.base import U_MAX_V, Measurement, RunContext
from gantry_twin.health.estimator_replay import estimator_replay
from gantry_twin.health.monitor import MachineMonitor, MonitorReport
from gantry_twin.sysid.logs import Log
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
