"""Bad tune specs and options: one line naming the file and the field, exit 2, nothing written."""

from __future__ import annotations

import pytest

from .helpers import run_main

GOOD = """\
set: {controller.name: pd, controller.options: {kp_v_m: [10000, 10000], kd_v_s_m: [100, 100]}, duration_s: 0.2,
      plant.model: paper}
scenarios: [{scenario: no_load_circle}]
design:
  - {field: controller.options.kp_v_m.0, low: 1000, high: 100000, log: true, name: kp_x}
goals:
  - {metric: contour_rms_um, limit: 10, kind: soft}
  - {metric: du_rms_v, limit: 2, relative: true}
"""

BAD = {
    "unknown design field": (
        GOOD.replace("controller.options.kp_v_m.0", "controller.options.kp_bogus"),
        "kp_bogus",
    ),
    "unknown top-level field": (GOOD + "bogus: 1\n", "bogus"),
    "empty range": (GOOD.replace("low: 1000, high: 100000", "low: 5000, high: 5000"), "design[0].high"),
    "reversed range": (GOOD.replace("low: 1000, high: 100000", "low: 100000, high: 1000"), "range is empty"),
    "log range through 0": (GOOD.replace("low: 1000, high: 100000", "low: 0, high: 100000"), "design[0].low"),
    "goal on an unknown metric": (GOOD.replace("metric: du_rms_v", "metric: du_peak"), "goals[1].metric"),
    "negative limit": (GOOD.replace("limit: 10,", "limit: -1,"), "goals[0].limit"),
    "no soft goal": (GOOD.replace("kind: soft", "kind: hard"), "soft goals"),
    "trials 0": (GOOD + "optimiser: {trials: 0}\n", "optimiser.trials"),
    "unknown scenario": (GOOD.replace("no_load_circle", "no_such_scenario"), "scenarios[0].scenario"),
    "design value the schema refuses": (GOOD.replace("high: 100000", "high: 1000000"), "kp_v_m"),
    "a design field also set": (
        GOOD.replace("plant.model: paper}", "plant.model: paper, payload.mass_kg: 1}").replace(
            "controller.options.kp_v_m.0", "payload.mass_kg"
        ),
        "also in set",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_spec_is_one_line_exit_2_nothing_written(tmp_path, capsys, case):
    text, names = BAD[case]
    spec = tmp_path / "bad.yaml"
    spec.write_text(text)
    out = tmp_path / "out"
    code, stdout, err = run_main(["tune", str(spec), "--out", str(out)], capsys)
    assert code == 2, (case, err)
    assert len(err.strip().splitlines()) == 1, err
    assert names in err and "bad.yaml" in err, err
    assert not out.exists()


@pytest.mark.parametrize(
    ("option", "names"),
    [
        (["--trials", "0"], "--trials"),
        (["--trials", "-3"], "--trials"),
        (["--seed", "-1"], "--seed"),
        (["--workers", "0"], "--workers"),
        (["--scheduler", "not an address"], "--scheduler"),
    ],
)
def test_bad_options_are_exit_2_nothing_written(tmp_path, capsys, option, names):
    spec = tmp_path / "good.yaml"
    spec.write_text(GOOD)
    out = tmp_path / "out"
    code, _, err = run_main(["tune", str(spec), "--out", str(out), *option], capsys)
    assert code == 2 and names in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_a_study_in_out_needs_resume(tmp_path, capsys):
    spec = tmp_path / "good.yaml"
    spec.write_text(GOOD)
    out = tmp_path / "out"
    out.mkdir()
    (out / "study.db").write_bytes(b"kept")
    code, _, err = run_main(["tune", str(spec), "--out", str(out)], capsys)
    assert code == 2 and "--resume" in err
    assert (out / "study.db").read_bytes() == b"kept"


def test_the_shipped_tunes_plan():
    from gantry_twin.tune import load_tune, plan_tune, tune_file

    for name in ("diarc_paper_paths", "pd_baseline"):
        path = tune_file(name)
        plan = plan_tune(load_tune(path), str(path))
        # the nominal member's runs (a goal's own runs on it included) come first, scenario 0's plain run first of all
        assert plan.nominal >= len(plan.spec.scenarios)
        assert [c.member == 0 for c in plan.cases] == [i < plan.nominal for i in range(len(plan.cases))]
        assert plan.cases[0].scenario == 0 and plan.cases[0].goal is None
        # every plant is named in the spec, never the scenario's default
        assert all("plant.model" in m.set for m in plan.spec.ensemble)


def test_an_unreachable_scheduler_is_exit_2_nothing_written(tmp_path, capsys):
    spec = tmp_path / "good.yaml"
    spec.write_text(GOOD)
    out = tmp_path / "out"
    code, _, err = run_main(["tune", str(spec), "--out", str(out), "--scheduler", "tcp://127.0.0.1:9"], capsys)
    assert code == 2 and "cannot connect" in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_the_best_line_says_when_no_trial_improved_on_the_baseline():
    from gantry_twin.cli.tune import best_line

    baseline = {"lam_x": 300.0, "ks_x": 40.0}
    assert (
        best_line(baseline, 0, dict(baseline)) == "best: trial 0 (the scenarios' own values: no trial improved on them)"
    )
    assert best_line(baseline, 7, {"lam_x": 310.0, "ks_x": 40.0}) == "best: trial 7"
