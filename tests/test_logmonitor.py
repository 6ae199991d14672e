"""``monitor --log``: DIARC's estimator and the health monitor over a recorded log, no plant (docs/logs.md)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gantry_twin.cli import main
from gantry_twin.health.log_monitor import estimates
from gantry_twin.outputs.files import write_parquet
from gantry_twin.outputs.tracefile import trace_table
from gantry_twin.run import execute
from gantry_twin.scenario import build, dump_yaml, load_scenario, shipped
from gantry_twin.sysid.logs import read_log, write_log


def _built(name: str, *overrides: str):
    scenario = load_scenario(shipped(name), list(overrides))
    return scenario, build(scenario, str(shipped(name)))


def test_estimates_over_a_log_are_those_the_run_logged(tmp_path):
    """The estimator replayed over (t, u, encoder positions) gives DIARC's logged theta^ of the run."""
    scenario, built = _built(
        "no_load_circle",
        "duration_s=2",
        "window_s=[0.5, 1.5]",
        "estimates_window_s=[1, 2]",
        "controller.options.estimator=recommended",
    )
    trace = execute(built)
    write_log(tmp_path / "log.parquet", trace.t_s, trace.u_v, trace.q_meas_m, trace.q_d_m)
    log = read_log(tmp_path / "log.parquet")
    fresh = build(scenario, str(shipped("no_load_circle"))).controller
    theta = estimates(fresh, log)
    logged = trace.controller_state["theta_hat"]
    assert np.ptp(logged[trace.t_s >= 0.5], axis=0).max() > 1e-3  # the estimates move: the comparison means something
    # The same kernels in the same order, to rounding (compiled into another kernel, numba may order a sum
    # differently); the first sample's velocity, which a log lacks, is the twin's first backward difference too.
    np.testing.assert_allclose(theta, logged, rtol=0, atol=1e-9)


def test_monitor_log_with_a_baseline_from_an_earlier_log(tmp_path, capsys):
    """``--baseline``: an earlier log's summary.json (its mean estimates) is the baseline, as a scenario's
    monitor.baseline_summary would make it."""
    _, built = _built("no_load_circle", "duration_s=2", "window_s=[0.5, 1.5]", "estimates_window_s=[1, 2]")
    trace = execute(built)
    write_log(tmp_path / "log.parquet", trace.t_s, trace.u_v, trace.q_meas_m, trace.q_d_m)
    log = str(tmp_path / "log.parquet")
    first, second = tmp_path / "first", tmp_path / "second"
    judged = ["--set", "monitor.judge_from_s=0.5"]
    # A 2 s log never leaves the default 20-30 s baseline window: refused, not a silent "0 alarms".
    assert main(["monitor", "--log", log, "--out", str(tmp_path / "refused"), *judged]) == 2
    assert "inside the monitor's baseline window [20, 30] s" in capsys.readouterr().err
    assert not (tmp_path / "refused").exists()
    inside = ["--set", "monitor.baseline_window_s=[0.5, 1]"]
    assert main(["monitor", "--log", log, "--out", str(first), *judged, *inside]) == 0
    commissioning = json.loads((first / "summary.json").read_text())
    assert commissioning["health"]["judged"]  # it judged something this time
    assert (
        main(["monitor", "--log", log, "--baseline", str(first / "summary.json"), "--out", str(second), *judged]) == 0
    )
    health = json.loads((second / "summary.json").read_text())["health"]
    assert health["baseline"]["source"].startswith("commissioning run")
    assert health["baseline"]["M1"] == commissioning["estimates"]["M1"]["estimate"]
    assert health["status"]["M1"] != "baseline"
    assert "baseline: commissioning run" in capsys.readouterr().out


def test_a_log_that_starts_late_is_judged_from_its_first_sample(tmp_path, capsys):
    """A recording cut out of a machine's day (t_s from 100 s): its windows count from its first sample, so it is
    judged as the same samples from t = 0 are; the alarms and status are the same, the times 100 s later."""
    _, built = _built("no_load_circle", "duration_s=2", "window_s=[0.5, 1.5]", "estimates_window_s=[1, 2]")
    trace = execute(built)
    logs = {0.0: tmp_path / "at-zero.parquet", 100.0: tmp_path / "late.parquet"}
    for t0, path in logs.items():
        write_log(path, trace.t_s + t0, trace.u_v, trace.q_meas_m, trace.q_d_m)
    late = str(logs[100.0])
    # The default baseline window, 20-30 s from the first sample, lies beyond a 2 s log wherever it starts.
    assert main(["monitor", "--log", late, "--out", str(tmp_path / "refused")]) == 2
    assert "ends at 2 s after its first sample (t = 100 s), inside the monitor's baseline window [20, 30] s" in (
        capsys.readouterr().err
    )
    window = ["--set", "monitor.baseline_window_s=[0.5, 1]", "--set", "monitor.tolerance_pct=1"]
    health = {}
    for t0, path in logs.items():
        assert main(["monitor", "--log", str(path), "--out", str(tmp_path / f"o{t0:g}"), *window]) == 0
        health[t0] = json.loads((tmp_path / f"o{t0:g}" / "summary.json").read_text())["health"]
    assert health[100.0]["judged"] and health[100.0]["status"] == health[0.0]["status"]
    assert health[100.0]["baseline"]["source"] == "this run, mean over 0.5-1 s from its first sample (t = 100.5-101 s)"
    assert health[100.0]["alarms"], "a 1 % tolerance raises alarms: the comparison means something"
    for a, b in zip(health[100.0]["alarms"], health[0.0]["alarms"], strict=True):
        assert (a["parameter"], a["since_start_s"]) == (b["parameter"], pytest.approx(b["time_s"], abs=1e-9))
        assert a["time_s"] == pytest.approx(b["time_s"] + 100.0, abs=1e-9)


def test_monitor_log_without_diarc_is_bad_input(tmp_path, capsys):
    t = np.arange(100) * 2e-4
    write_log(tmp_path / "log.csv", t, np.zeros((100, 2)), np.zeros((100, 2)), None)
    code = main(["monitor", "--log", str(tmp_path / "log.csv"), "--controller", "pd", "--out", str(tmp_path / "o")])
    assert code == 2
    assert "DIARC" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("factor", "answer"),
    [
        (
            1e3,
            "its sample period is 0.2 s (t_s in seconds), not the machine's 0.2 ms: t_s looks like milliseconds;"
            " give t_s in seconds",
        ),
        (5.0, "its sample period is 0.001 s (t_s in seconds), not the machine's 0.2 ms; give a log sampled at it"),
    ],
)
def test_monitor_log_at_another_sample_period_is_refused_naming_the_unit(tmp_path, capsys, factor, answer):
    """t_s in milliseconds (a 6000 s "log" at 0.2 s) once gave 0 alarms; now: exit 2, one line, nothing written."""
    t = np.arange(1000) * 2e-4 * factor
    write_log(tmp_path / "log.csv", t, np.zeros((1000, 2)), np.zeros((1000, 2)), None)
    out = tmp_path / "o"
    code = main(["monitor", "--log", str(tmp_path / "log.csv"), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [f"gantry-twin: error: --log {tmp_path / 'log.csv'}: {answer}"]
    assert not out.exists()


@pytest.mark.slow
def test_friction_drift_circle_same_alarms_from_its_trace(tmp_path, capsys):
    """Acceptance: the trace of friction_drift_circle monitored as a log raises the simulated monitor's alarms.

    The first 56 s of the scenario's 90: its baseline (10-20 s), the drift from 20 s, and on this plant (the rig) its
    B2 alarm at about 50.3 s; the run's own monitor and the log's see the same 56 s."""
    scenario, built = _built("friction_drift_circle", "duration_s=56")
    trace = execute(built)
    simulated = built.monitor.report().alarms
    assert simulated, "the scenario's drift must raise an alarm"
    write_parquet(tmp_path / "trace.parquet", trace_table(trace))
    out = tmp_path / "log-monitor"
    code = main(["monitor", "friction_drift_circle", "--log", str(tmp_path / "trace.parquet"), "--out", str(out)])
    assert code == 0
    alarms = json.loads((out / "summary.json").read_text())["health"]["alarms"]
    assert [a["parameter"] for a in alarms] == [a.parameter for a in simulated]
    for a, s in zip(alarms, simulated, strict=True):
        assert abs(a["time_s"] - s.time_s) <= 0.5
    assert (
        main(
            [
                "monitor",
                "friction_drift_circle",
                "--log",
                str(tmp_path / "trace.parquet"),
                "--out",
                str(out),
                "--fail-on-alarm",
            ]
        )
        == 3
    )
    # A run's directory (its trace and its resolved scenario, as gantry-twin run writes them): monitored with the
    # run's own settings without naming the scenario; the same alarms at the same times as the run's monitor.
    (tmp_path / "scenario.yaml").write_text(dump_yaml(scenario.resolved()), encoding="utf-8")
    own = tmp_path / "own-settings"
    assert main(["monitor", "--log", str(tmp_path), "--out", str(own)]) == 0
    alarms = json.loads((own / "summary.json").read_text())["health"]["alarms"]
    assert [(a["parameter"], a["time_s"]) for a in alarms] == [(a.parameter, a.time_s) for a in simulated]
    assert "the run's own settings, from" in capsys.readouterr().err
