"""The whole-run figures of gantry_twin.metrics.RunMetrics against numpy on the whole series, however it is cut."""

from __future__ import annotations

import numpy as np
import pytest

from gantry_twin.loop.trace import Trace
from gantry_twin.metrics import RunMetrics, carried_sum

TS = 2e-4


def synthetic_trace(n: int = 40_000, seed: int = 1) -> Trace:
    """A trace of n samples with random errors (um scale) and commands (V), no physics needed."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * TS
    drift = 1.0 + t / t[-1]  # eps_c grows over the run: the per-period rms must show it
    return Trace(
        t_s=t,
        q_m=np.zeros((n, 2)),
        q_meas_m=np.zeros((n, 2)),
        q_d_m=np.zeros((n, 2)),
        e_m=rng.normal(0.0, 2e-6, (n, 2)),
        eps_n_m=np.zeros(n),
        eps_c_m=rng.normal(0.0, 1e-6, n) * drift,
        u_v=rng.uniform(-3.0, 3.0, (n, 2)) * [1.0, 2.0],
        disturbance_v=np.zeros((n, 2)),
        true_theta=np.zeros(8),
        filled=n,
    )


def feed(metrics: RunMetrics, trace: Trace, cuts: list[int]) -> RunMetrics:
    bounds = [0, *cuts, trace.filled]
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        metrics.on_chunk(trace, a, b)
    return metrics


def new_metrics(duration_s: float) -> RunMetrics:
    # contour window [1.5, 3.0) s; whole run [1.5, end); periods of 1.5 s from 0.25 s
    return RunMetrics((1.5, 3.0), (6.0, 8.0), (1.5, duration_s), (0.25, 1.5))


def test_whole_run_figures_are_numpy_over_the_windows():
    trace = synthetic_trace()
    t, duration = trace.t_s, trace.filled * TS
    whole = feed(new_metrics(duration), trace, []).whole_run()
    inside = t >= 1.5
    eps_um = np.abs(trace.eps_c_m[inside]) * 1e6
    assert whole.window_s == (1.5, duration) and whole.command_window_s == (0.0, duration)
    assert whole.contour_rms_um == pytest.approx(np.sqrt(np.mean(eps_um**2)), rel=1e-12)
    assert whole.contour_max_um == eps_um.max()
    axial = np.sqrt(np.mean((trace.e_m[inside] * 1e6) ** 2, axis=0))
    assert whole.axial_rms_um == pytest.approx(tuple(axial), rel=1e-12)
    assert whole.max_abs_command_v == tuple(np.abs(trace.u_v).max(axis=0))  # the whole run, not the window
    # Periods [0.25 + 1.5 k, 0.25 + 1.5 (k + 1)) up to the end (8 s): 5 whole periods and 0.25 s.
    expected = []
    for k in range(6):
        sel = (t >= 0.25 + 1.5 * k) & (t < 0.25 + 1.5 * (k + 1))
        expected.append(np.sqrt(np.mean((trace.eps_c_m[sel] * 1e6) ** 2)))
    assert whole.periods_start_s == 0.25 and whole.period_s == 1.5
    assert whole.period_rms_um == pytest.approx(tuple(expected), rel=1e-9)
    assert whole.period_rms_um[4] > 1.5 * whole.period_rms_um[0]  # the drift shows


@pytest.mark.parametrize("cuts", [[1], [7, 8, 9], [12_499, 12_500, 12_501], list(range(997, 40_000, 997))])
def test_whole_run_figures_do_not_depend_on_how_the_run_is_cut(cuts):
    """A run held in pieces writes the summary of a whole trace to the byte: the same floats, not close ones."""
    trace = synthetic_trace()
    duration = trace.filled * TS
    whole = feed(new_metrics(duration), trace, []).whole_run()
    assert feed(new_metrics(duration), trace, cuts).whole_run() == whole


def test_carried_sum_is_sequential():
    rows = np.random.default_rng(3).normal(size=(1000, 2)) * 1e6
    once = carried_sum(np.zeros(2), rows)
    twice = carried_sum(carried_sum(np.zeros(2), rows[:333]), rows[333:])
    assert np.array_equal(once, twice)
    assert np.allclose(once, rows.sum(axis=0), rtol=1e-12)


def test_no_whole_run_without_its_window():
    trace = synthetic_trace(2000)
    assert feed(RunMetrics((0.1, 0.2), (0.2, 0.4)), trace, []).whole_run() is None
