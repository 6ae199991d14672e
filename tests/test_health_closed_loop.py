"""The health monitor on DIARC's estimates in closed loop, with plant changes: its acceptance (docs/health.md).

Runs the shipped scenarios through gantry_twin.scenario load/build and the CLI's execute, as
``gantry-twin monitor`` does (the compiled loop: a 90 s run takes a few seconds), on the ideal plant
(``plant.model=paper``): the acceptance judges the estimates against a truth the estimator models
exactly (Coulomb + viscous friction). On the rig plant, the default machine, the same scenarios'
estimates carry the LuGre plant's few-percent bias (docs/rig-plant.md, Tables 3-4).
"""

from __future__ import annotations

import numpy as np
import pytest

from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.cli.app import EXIT_ALARM, EXIT_OK, main
from gantry_twin.controllers import DIARC, RECOMMENDED_ESTIMATOR
from gantry_twin.controllers.law import THETA_MAX, THETA_MIN
from gantry_twin.health.monitor import NOT_EXCITED, Baseline, ExcitationSettings, HealthSettings, MachineMonitor
from gantry_twin.metrics import contour_metrics
from gantry_twin.plant.model import THETA_NAMES
from gantry_twin.run import execute
from gantry_twin.scenario import build, load_scenario, shipped

#: The plant these acceptances are about.
IDEAL = "plant.model=paper"


def run(name, *overrides):  # noqa: ANN001, ANN201
    path = shipped(name)
    built = build(load_scenario(path, [IDEAL, *overrides]), str(path))
    trace = execute(built)
    report = built.monitor.report() if built.monitor is not None else None
    return built, trace, report


def relative_error(trace, j):  # noqa: ANN001, ANN201
    true = trace.true_parameters_t()[:, j]
    return (trace.controller_state["theta_hat"][:, j] - true) / true


@pytest.mark.slow
def test_friction_drift_b2_tracked_and_only_b2_alarms():
    _, trace, report = run("friction_drift_circle")
    t = trace.t_s
    true_b2 = trace.true_parameters_t()[:, 3]
    assert true_b2[0] == pytest.approx(0.7) and true_b2[-1] == pytest.approx(0.91)
    assert np.abs(relative_error(trace, 3)[t >= 25.0]).max() < 0.05
    # The true B2 passes +10 % (0.77 V/(m/s)) at t = 40 s.
    crossing = t[np.argmax(true_b2 > 0.77 + 1e-12)]
    assert crossing == pytest.approx(40.0, abs=1e-3)
    assert [a.parameter for a in report.alarms] == ["B2"]
    alarm = report.alarms[0]
    assert crossing < alarm.time_s <= crossing + 5.0
    assert alarm.direction == "up" and alarm.change_pct > 10.0


@pytest.mark.slow
def test_payload_pickup_masses_tracked_within_4_s_and_alarmed():
    _, trace, report = run("payload_pickup_circle")
    t = trace.t_s
    true = trace.true_parameters_t()
    assert true[-1, 0] == pytest.approx(0.12 + 5.0 / 69.0) and true[-1, 1] == pytest.approx(0.5 + 5.0 / 69.0)
    after = t >= 24.0
    for j in (0, 1):
        assert np.abs(relative_error(trace, j)[after]).max() < 0.05, THETA_NAMES[j]
    raised = {a.parameter: a for a in report.alarms}
    for name in ("M1", "M2"):
        alarm = raised[name]
        assert 20.0 < alarm.time_s < 24.0 and alarm.direction == "up" and alarm.change_pct > 10.0
        assert alarm.change == pytest.approx(alarm.estimate - alarm.baseline)
    assert report.final_status()["M1"] == "alarm" and report.final_status()["M2"] == "alarm"


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",
    # The circle without load and the ellipse with it in the suite; the other two with -m exhaustive (suite time).
    ["no_load_circle", pytest.param("no_load_ellipse", marks=pytest.mark.exhaustive)]
    + [pytest.param("load_5kg_circle", marks=pytest.mark.exhaustive), "load_5kg_ellipse"],
)
def test_paper_scenarios_raise_no_alarm_over_60_s(name):
    _, _, report = run(name, "duration_s=60", "monitor.enable=true")
    assert report.alarms == []
    final = report.final_status()
    # All "ok" at the end, judged; except that the paper's 250 / 150 Hz filters leave encoder noise in x_f''
    # that biases M (errors in variables, docs/estimator-envelope.md): excited, but not always trusted.
    assert all(final[n] == "ok" for n in final if n not in ("M1", "M2"))
    assert final["M1"] in ("ok", "untrustworthy") and final["M2"] in ("ok", "untrustworthy")
    assert report.excited[-1].all()


def test_standstill_is_not_excited_and_raises_no_alarm():
    """The reference stands still (rate ~0): nothing slides, no parameter is judged."""
    healthy = Baseline((0.12, 0.5, 0.5, 0.7, 0.1, 0.15, 0.0, 0.0))
    monitor = MachineMonitor(ExcitationSettings(filter_hz=(50.0, 50.0)), HealthSettings(judge_from_s=0.5), healthy)
    simulate(Plant(), circle(), TimingLaw(1e-9), DIARC(estimator=RECOMMENDED_ESTIMATOR), 5.0, observers=[monitor])
    report = monitor.report()
    assert report.alarms == []
    judged = report.t_s >= 0.5
    assert not report.excited[judged].any()
    assert (report.status[judged] == NOT_EXCITED).all()
    assert (report.level_v[judged] < 1e-3).all()


@pytest.mark.parametrize("name", ["step_disturbance_circle", "step_disturbance_ellipse"])
def test_step_disturbance_alarms_on_dn2(name):
    _, _, report = run(name, "duration_s=8", "monitor.enable=true", "monitor.baseline_window_s=[1.0, 1.8]")
    dn2 = [a for a in report.alarms if a.parameter == "dN2"]
    assert dn2 and 1.86 < dn2[0].time_s < 3.0 and dn2[0].direction == "up"
    assert dn2[0].change > 0.1  # volts: part of the unseen 0.6 V step


@pytest.mark.slow
def test_cogging_keeps_diarc_within_twice_its_ripple_free_error():
    """The recommended estimator's fast compensation (gamma_d = 3e4) absorbs the ripple;
    with the paper's 1e4 the same scenario grows 2.3x (docs/health.md).

    The scenario's metrics are over its second period, [pi, 2 pi] s; the loop is causal, so the first 6.5 s of its
    30 s give the same metrics to the last bit."""
    scenario, first = "cogging_circle", "duration_s=6.5"
    _, ripple, _ = run(scenario, first)
    built, clean, _ = run(scenario, first, "changes.cogging=[]")
    assert built.scenario.metric_window_s == pytest.approx((np.pi, 2 * np.pi))
    window = built.scenario.metric_window_s
    with_ripple, without = contour_metrics(ripple, window).rms_um, contour_metrics(clean, window).rms_um
    assert with_ripple > without  # the ripple acted
    assert with_ripple < 2.0 * without


@pytest.mark.slow
def test_single_encoder_spike_is_survived():
    spike_s = 10.0
    glitch = f"changes.encoder_glitch=[{{kind: spike, time_s: {spike_s}, axis: x, offset_m: 5.0e-5}}]"
    built, trace, _ = run("no_load_circle", "duration_s=12", "controller.options.estimator=recommended", glitch)
    t = trace.t_s
    k = int(round(spike_s / trace.sample_period_s))
    assert trace.q_meas_m[k, 0] - trace.q_m[k, 0] == pytest.approx(5e-5, abs=1e-6)
    theta = trace.controller_state["theta_hat"]
    assert np.isfinite(theta).all() and np.isfinite(trace.u_v).all()
    assert (theta >= np.array(THETA_MIN) - 1e-12).all() and (theta <= np.array(THETA_MAX) + 1e-12).all()
    # Recovery: from 0.1 s after the spike the contour error is back at the spike-free run's level
    # (rms over the next second within 5 %; no sample more than a quarter of that level off it).
    _, clean, _ = run("no_load_circle", "duration_s=12", "controller.options.estimator=recommended")
    level = np.sqrt(np.mean(clean.eps_c_m[(t >= spike_s - 1.0) & (t < spike_s)] ** 2))
    gap = np.abs(trace.eps_c_m - clean.eps_c_m)
    assert gap[t < spike_s].max() == 0.0
    assert gap[(t >= spike_s) & (t < spike_s + 0.1)].max() > level  # the spike disturbed the loop
    assert gap[t >= spike_s + 0.1].max() < 0.25 * level
    after = (t >= spike_s + 0.1) & (t < spike_s + 1.1)
    assert np.sqrt(np.mean(trace.eps_c_m[after] ** 2)) <= 1.05 * np.sqrt(np.mean(clean.eps_c_m[after] ** 2))


@pytest.mark.slow
@pytest.mark.parametrize(("overrides", "code"), [((), EXIT_ALARM), (("changes.payload_change=[]",), EXIT_OK)])
def test_monitor_fail_on_alarm_exit_status(tmp_path, capsys, overrides, code):
    args = [
        "monitor",
        str(shipped("payload_pickup_circle")),
        "--out",
        str(tmp_path),
        "--fail-on-alarm",
        "--set",
        "duration_s=24",
        *[x for o in overrides for x in ("--set", o)],
    ]
    assert main(args) == code
    printed = capsys.readouterr().out
    if code == EXIT_ALARM:
        assert "ALARM" in printed and "M1 up" in printed
    else:
        assert "health: 0 alarms" in printed
    assert (tmp_path / "summary.json").is_file()
