"""The excitation and health monitors (gantry_twin.health.monitor) on synthetic and short real traces."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gantry_twin import Plant, SensingConfig, TimingLaw, circle, simulate
from gantry_twin.controllers import create
from gantry_twin.health.excitation import FilteredRegressors, accumulate_information, accumulate_moment
from gantry_twin.health.monitor import (
    ALARM,
    NOT_EXCITED,
    UNTRUSTWORTHY,
    Baseline,
    ExcitationSettings,
    HealthSettings,
    MachineMonitor,
    monitor_trace,
)
from gantry_twin.loop.trace import Trace
from gantry_twin.numerics.jit import reference

TS = 2.0e-4
BASE = (0.12, 0.50, 0.50, 0.70, 0.10, 0.15, 0.0, 0.0)
PERIOD = 0.01


def synthetic_trace(
    duration_s: float, theta_of_t, moving: bool = True, rate_rad_s: float = 2.0, t0_s: float = 0.0
) -> Trace:
    """A trace whose positions follow the paper circle (or stand still) and whose theta_hat is given, both as
    functions of the time since its first sample; that first sample at ``t0_s``."""
    t = np.arange(int(round(duration_s / TS))) * TS
    if moving:
        q = 0.2 * np.column_stack([np.sin(rate_rad_s * t), -np.cos(rate_rad_s * t)])
    else:
        q = np.tile([0.01, -0.02], (t.size, 1))
    q = np.round(q / 0.5e-6) * 0.5e-6  # the encoder
    nan = np.full((t.size, 2), np.nan)
    return Trace(
        t_s=t + t0_s,
        q_m=q,
        q_meas_m=q,
        q_d_m=q,
        e_m=nan,
        eps_n_m=nan[:, 0],
        eps_c_m=nan[:, 0],
        u_v=nan,
        disturbance_v=np.zeros((t.size, 2)),
        true_theta=np.array(BASE),
        controller_state={"theta_hat": theta_of_t(t)},
        filled=t.size,
        timestep_s=TS,  # as a log's or a stream's trace gives it: t_s[1] - t_s[0] at t0_s = 100 s is not TS
    )


def constant(theta=BASE):
    return lambda t: np.tile(theta, (t.size, 1))


HEALTH = HealthSettings(decision_interval_s=0.2, judge_from_s=2.5)
GIVEN = Baseline(tuple(x if i < 6 else 0.0 for i, x in enumerate(BASE)), "test")


def row_at(report, t_s: float) -> int:
    return int(np.argmin(np.abs(report.t_s - t_s)))


# ---- excitation --------------------------------------------------------------------------------


def test_standstill_has_zero_information():
    report = monitor_trace(synthetic_trace(3.0, constant(), moving=False), health=HEALTH, baseline=GIVEN)
    assert np.all(report.information == 0.0)
    assert np.all(report.level_v == 0.0)
    assert np.all(report.parameter_v < 1e-9)
    assert not report.excited.any()


def test_circle_excites_every_parameter_of_both_axes():
    report = monitor_trace(synthetic_trace(4.0, constant()), health=HEALTH, baseline=GIVEN)
    late = report.t_s >= 2.5
    assert np.all(report.level_v[late] > 0.005)
    assert np.all(report.parameter_v[late] > 0.02)
    assert report.excited[late].all()
    # Every window's information is symmetric positive definite.
    eig = np.linalg.eigvalsh(report.information[late])
    assert np.all(eig > 0.0)


def test_information_is_the_integral_of_the_filtered_regressor():
    """Independent check of eq. (29) on the X axis of an unquantised circle: the window integral
    of g g^T with the filtered signals in closed form. Hf (250 Hz) delays them by 2 zeta / wn and
    its gain at 2 rad/s is 1 to 1e-6; the first-order hold of the position (chords of the curve,
    on average Ts^2 q''/12 inside it) shrinks x_f'' by wn^2 Ts^2 / 12 = 0.8 %; samples with
    |x_f'| < 1 mm/s (stick) are left out."""
    w, r = 2.0, 0.2
    trace = synthetic_trace(4.0, constant(), rate_rad_s=w)
    trace.q_meas_m[:] = r * np.column_stack([np.sin(w * trace.t_s), -np.cos(w * trace.t_s)])
    report = monitor_trace(trace, ExcitationSettings(window_s=2.0), health=HEALTH, baseline=GIVEN)
    k = row_at(report, 3.5 - TS)
    t = report.t_s[k] - np.arange(10000)[::-1] * TS
    wn = 2 * math.pi * 250
    tl = t - 2 * 0.7 / wn
    acc = -r * w**2 * np.sin(w * tl) * (1 - wn**2 * TS**2 / 12)
    vel = r * w * np.cos(w * tl)
    g = np.column_stack([acc, vel, -np.ones_like(t)])[np.abs(vel) >= 1e-3]
    expected = g.T @ g * TS
    got = report.information[k, 0][np.ix_([0, 1, 3], [0, 1, 3])]
    np.testing.assert_allclose(got, expected, rtol=1e-3, atol=1e-5 * np.abs(expected).max())


def test_period_sums_of_information_and_moment_kernels():
    """accumulate_information / accumulate_moment: each closed period holds sum_k w_k g_k g_k^T (and
    [sum w e g, sum w |size| |g|]) of its own samples, the open period carries over to the next call, and the
    compiled kernels give the bits of the same code uncompiled."""
    rng = np.random.default_rng(3)
    n, p, period, first = 23, 5, 7, 4  # periods close after global samples 6, 13, 20, 27 (k = 2, 9, 16)
    g = rng.normal(size=(n, 2, p))
    weight = np.where(rng.random((n, 2)) < 0.8, 2e-4, 0.0)
    error, size = rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    results = []
    for info_kernel, moment_kernel in (
        (accumulate_information, accumulate_moment),
        (reference(accumulate_information), reference(accumulate_moment)),
    ):
        acc, moving, blocks, block_moving = (
            np.zeros((2, p, p)),
            np.zeros(2),
            np.full((4, 2, p, p), 9.0),
            np.zeros((4, 2)),
        )
        m = info_kernel(g, weight, first, period, acc, moving, blocks, block_moving)
        moment_acc, moments = np.zeros((2, 2, 4)), np.full((4, 2, 2, 4), 9.0)
        assert moment_kernel(g[:, :, :4], error, size, weight, first, period, moment_acc, moments) == m == 3
        results.append((blocks[:m], block_moving[:m], acc, moving, moments[:m], moment_acc))
    bounds = [0, 3, 10, 17, n]  # the periods' first samples, and the end
    for i, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        info = np.einsum("ka,kai,kaj->aij", weight[lo:hi], g[lo:hi], g[lo:hi])
        used = (weight[lo:hi] != 0.0).sum(axis=0)
        signed = np.einsum("ka,kai->ai", weight[lo:hi] * error[lo:hi], g[lo:hi, :, :4])
        unsigned = np.einsum("ka,kai->ai", weight[lo:hi] * np.abs(size[lo:hi]), np.abs(g[lo:hi, :, :4]))
        got = results[0]
        if i < 3:
            np.testing.assert_allclose(got[0][i], info, rtol=1e-12, atol=1e-20)
            np.testing.assert_array_equal(got[1][i], used / period)
            np.testing.assert_allclose(got[4][i], np.stack([signed, unsigned]), rtol=1e-12, atol=1e-20)
        else:  # the open period, carried over
            np.testing.assert_allclose(got[2], info, rtol=1e-12, atol=1e-20)
            np.testing.assert_array_equal(got[3], used)
            np.testing.assert_allclose(got[5], np.stack([signed, unsigned]), rtol=1e-12, atol=1e-20)
    for compiled, uncompiled in zip(*results, strict=True):
        np.testing.assert_array_equal(compiled, uncompiled)


def closed_loop(duration_s: float, chunk_s: float, observers=()):
    return simulate(
        Plant(),
        circle(),
        TimingLaw(2.0),
        create("diarc"),
        duration_s,
        sensing=SensingConfig(),
        observers=observers,
        chunk_s=chunk_s,
    )


@pytest.fixture(scope="module")
def short_run():
    """A real 2.6 s DIARC circle run, monitored live with chunks that do not align with periods."""
    settings = ExcitationSettings(window_s=2.0)
    health = HealthSettings(baseline_window_s=(0.5, 1.5))
    live = MachineMonitor(settings, health)
    trace = closed_loop(2.6, 0.037, observers=[live])
    return trace, live.report(), settings, health


def test_excitation_positive_on_a_real_circle_run(short_run):
    trace, report, _, _ = short_run
    full = report.t_s >= 2.0
    assert np.all(report.level_v[full] > 0.0)
    assert np.all(report.parameter_v[full][:, :6] > 0.01)


def test_incremental_equals_offline(short_run):
    trace, live, settings, health = short_run
    offline = monitor_trace(trace, settings, health)
    for name in (
        "t_s",
        "information",
        "level_v",
        "parameter_v",
        "moving",
        "excited",
        "estimate",
        "deviation",
        "cusum",
        "status",
    ):
        np.testing.assert_array_equal(getattr(live, name), getattr(offline, name), err_msg=name)
    assert live.baseline == offline.baseline
    assert live.alarms == offline.alarms


# ---- health ------------------------------------------------------------------------------------


def test_cusum_matches_a_hand_computed_sequence():
    """B2 deviations y (tolerance units) per 10 ms period from 2.5 s: 0, 1.5, 3, 0.5, 0, -2.5, 2.
    By hand, with k = 1 and dt = 0.01 s: S+ = 0, .005, .025, .020, .010, 0, .010;
    S- = 0, 0, 0, 0, 0, .015, 0."""
    y = [0.0, 1.5, 3.0, 0.5, 0.0, -2.5, 2.0]
    s_up = [0.0, 0.005, 0.025, 0.020, 0.010, 0.0, 0.010]
    s_down = [0.0, 0.0, 0.0, 0.0, 0.0, 0.015, 0.0]

    def theta(t):
        out = np.tile(BASE, (t.size, 1))
        for i, yi in enumerate(y):
            sample_end = int(round((2.5 + i * PERIOD) / TS))  # the period ending at that time
            out[sample_end - 1, 3] = 0.7 * (1 + 0.1 * yi)
        return out

    report = monitor_trace(synthetic_trace(2.6, theta), health=HEALTH, baseline=GIVEN)
    first = row_at(report, 2.5 - TS)
    np.testing.assert_allclose(report.deviation[first : first + 7, 3], y, atol=1e-12)
    np.testing.assert_allclose(report.cusum[first : first + 7, 3, 0], s_up, atol=1e-12)
    np.testing.assert_allclose(report.cusum[first : first + 7, 3, 1], s_down, atol=1e-12)
    assert report.cusum[first - 1, 3].tolist() == [0.0, 0.0]  # nothing judged before judge_from_s


def test_constant_estimate_with_noise_raises_no_alarm():
    rng = np.random.default_rng(3)

    def theta(t):
        noisy = np.tile(BASE, (t.size, 1)) * (1 + 0.03 * rng.standard_normal((t.size, 8)))
        noisy[:, 6:] = 0.02 * rng.standard_normal((t.size, 2))
        return noisy

    report = monitor_trace(synthetic_trace(30.0, theta), health=HEALTH, baseline=GIVEN)
    assert report.alarms == []
    assert not np.any(report.status == ALARM)


def test_ramp_alarm_time_is_the_crossing_plus_the_cusum_delay():
    """B2 rising 0.5 %/s from 5 s (y = 0.05 (t - 5) tolerances): it crosses the 10 % tolerance at
    t_c = 25 s, then S+ = 0.025 (t - t_c)^2 reaches h = 0.2 after sqrt(0.2 / 0.025) = 2.83 s."""
    slope = 0.005

    def theta(t):
        out = np.tile(BASE, (t.size, 1))
        out[:, 3] = 0.7 * (1 + slope * np.clip(t - 5.0, 0.0, None))
        return out

    report = monitor_trace(synthetic_trace(30.0, theta), health=HEALTH, baseline=GIVEN)
    assert [a.parameter for a in report.alarms] == ["B2"]
    alarm = report.alarms[0]
    delay = math.sqrt(2 * HEALTH.decision_interval_s / (slope / 0.1))
    assert alarm.time_s == pytest.approx(25.0 + delay, abs=2 * PERIOD)
    assert alarm.direction == "up"
    assert alarm.change_pct == pytest.approx(100 * slope * (alarm.time_s - 5.0), abs=0.01)
    assert alarm.change == pytest.approx(0.7 * slope * (alarm.time_s - 5.0), rel=1e-3)


def test_windows_count_from_the_first_sample_of_a_trace_that_starts_late():
    """A log cut out of a machine's day, or a shadow that joined a running machine: the same samples 100 s later
    are judged the same (the baseline window and the judging start count from the first sample), and the alarm
    keeps the trace's time and gives the time since the first sample: the ramp's crossing at 25 s plus the CUSUM
    delay, computed by hand as in the test above."""
    slope = 0.005

    def theta(t):
        out = np.tile(BASE, (t.size, 1))
        out[:, 3] = 0.7 * (1 + slope * np.clip(t - 5.0, 0.0, None))
        return out

    health = HealthSettings(decision_interval_s=0.2, baseline_window_s=(1.0, 2.5))  # the baseline: BASE
    at_zero = monitor_trace(synthetic_trace(30.0, theta), health=health)
    late = monitor_trace(synthetic_trace(30.0, theta, t0_s=100.0), health=health)
    delay = math.sqrt(2 * health.decision_interval_s / (slope / 0.1))
    assert [a.parameter for a in late.alarms] == ["B2"] and late.baseline.theta == at_zero.baseline.theta
    assert late.alarms[0].since_start_s == pytest.approx(25.0 + delay, abs=2 * PERIOD)
    assert late.alarms[0].time_s == pytest.approx(late.alarms[0].since_start_s + 100.0, abs=1e-9)
    assert late.alarms[0].since_start_s == pytest.approx(at_zero.alarms[0].time_s, abs=1e-9)
    assert at_zero.alarms[0].since_start_s == at_zero.alarms[0].time_s  # a run from t = 0: the two clocks agree
    np.testing.assert_array_equal(late.status, at_zero.status)
    np.testing.assert_array_equal(late.cusum, at_zero.cusum)
    assert late.baseline.source == "this run, mean over 1-2.5 s from its first sample (t = 101-102.5 s)"
    assert "t = 127.83 s (27.83 s after the first sample): B2 up" in late.alarms[0].describe()


def test_step_on_nominal_disturbance_is_judged_in_volts():
    """dN2 steps to 0.6 V at 5 s: y = 6 tolerances, so S+ grows 5 per second and passes h = 0.2
    after 0.04 s."""

    def theta(t):
        out = np.tile(BASE, (t.size, 1))
        out[:, 7] = np.where(t >= 5.0, 0.6, 0.0)
        return out

    report = monitor_trace(synthetic_trace(7.0, theta), health=HEALTH, baseline=GIVEN)
    assert [a.parameter for a in report.alarms] == ["dN2"]
    assert report.alarms[0].time_s == pytest.approx(5.04, abs=2 * PERIOD)
    assert report.alarms[0].change_pct is None
    assert report.alarms[0].change == pytest.approx(0.6)


def test_standstill_raises_nothing_and_reports_not_excited():
    def theta(t):  # the estimates wander far off while nothing moves
        out = np.tile(BASE, (t.size, 1))
        out[:, 7] = 0.5
        out[:, 0] = 0.2
        return out

    report = monitor_trace(synthetic_trace(6.0, theta, moving=False), health=HEALTH, baseline=GIVEN)
    assert report.alarms == []
    judged = report.t_s >= 2.5
    assert np.all(report.status[judged] == NOT_EXCITED)
    assert set(report.final_status().values()) == {"not excited"}


def test_baseline_from_the_settling_window_of_the_run():
    def theta(t):
        out = np.tile(BASE, (t.size, 1))
        out[:, 0] = 0.12 + 0.01 * np.sin(t)
        return out

    health = HealthSettings(baseline_window_s=(1.0, 2.0))
    report = monitor_trace(synthetic_trace(2.5, theta), health=health)
    periods = np.arange(1.0, 2.0 - TS / 2, PERIOD) + PERIOD - TS  # period ends inside the window
    assert report.baseline.theta[0] == pytest.approx(np.mean(0.12 + 0.01 * np.sin(periods)), rel=1e-12)
    assert np.all(report.status[report.t_s < 2.0 - TS] == 0)  # "baseline" until the window closes


def test_monitor_filters_the_measurements_exactly_as_diarc_estimator():
    """FilteredRegressors over the recorded encoder positions ends in DIARC's own filter state and regressor."""
    controller = create("diarc")  # paper filters, 250 / 150 Hz, the ExcitationSettings default
    trace = simulate(Plant(), circle(), TimingLaw(2.0), controller, 0.3)
    regressors = FilteredRegressors(ExcitationSettings(), trace.sample_period_s)
    g, _ = regressors.advance(trace.q_meas_m[:100], trace.u_v[:100])
    g, _ = regressors.advance(trace.q_meas_m[100:], trace.u_v[100:])  # in two chunks, as the live observer feeds it
    estimator = controller.estimator.state
    # columns q, Sf, 1, u (the estimator's target u_f); column 4: the friction column's error
    np.testing.assert_array_equal(regressors.z[:, :, :4], estimator.z[:, :, :4])
    np.testing.assert_array_equal(regressors.u_f[-1], estimator.u_f)
    for axis in range(2):
        np.testing.assert_array_equal(g[-1, axis], estimator.regression[[axis, 2 + axis, 4 + axis, 6 + axis], axis])


def test_untrustworthy_estimates_are_not_judged():
    """With the paper's 250 Hz X filter the encoder's quantisation noise in x_f'' biases M1 (errors
    in variables, docs/estimator-envelope.md): M1 is excited on the circle but untrustworthy, so its jump raises
    nothing and its status says why; B2, trusted, is still judged and alarms on its own jump."""

    def theta(t):
        out = np.tile(BASE, (t.size, 1))
        out[:, 0] = np.where(t >= 4.0, 0.3, BASE[0])  # M1 x2.5
        out[:, 3] = np.where(t >= 5.0, 1.5 * BASE[3], BASE[3])  # B2 +50 %
        return out

    report = monitor_trace(synthetic_trace(7.0, theta), health=HEALTH, baseline=GIVEN)
    judged = report.t_s >= 2.5
    assert report.excited[judged, 0].all() and not report.trusted[judged, 0].any()
    assert report.bias[judged, 0].min() > ExcitationSettings().max_bias
    assert np.all(report.status[judged, 0] == UNTRUSTWORTHY)
    assert report.trusted[judged, 3].all()
    assert [a.parameter for a in report.alarms] == ["B2"]


def test_bias_bound_follows_the_encoder_noise():
    """The same run with ideal positions (resolution 0): nothing left to bias M1, it is trusted and judged."""

    def theta(t):
        out = np.tile(BASE, (t.size, 1))
        out[:, 0] = np.where(t >= 4.0, 0.3, BASE[0])
        return out

    ideal = ExcitationSettings(resolution_m=0.0)
    report = monitor_trace(synthetic_trace(7.0, theta), ideal, health=HEALTH, baseline=GIVEN)
    assert report.trusted[report.t_s >= 2.5, 0].all()
    assert [a.parameter for a in report.alarms] == ["M1"]
