"""`gantry-twin report`: paper / rig twin / ideal twin per cell, the acceptance checks, the reversal spike, and
`--rig FILE` (a calibration's plant) and `--no-ideal`."""

from __future__ import annotations

import json
import math

import numpy as np
import pyarrow.parquet as pq
import pytest

from gantry_twin.paths.contours import reference
from gantry_twin.reports import paper as report
from gantry_twin.reports import rig as rig_report
from gantry_twin.scenario import build, load_scenario, shipped

from .helpers import FLOAT32_REL, run_main, trace_column

TINY = ("duration_s=0.1", "window_s=[0.02, 0.1]", "estimates_window_s=[0.05, 0.1]")
#: A calibration's rig plant unlike the shipped one: LuGre with a Stribeck bump twice the Coulomb level on X.
RIG = ("plant.friction.model=lugre", "plant.friction.x.fs_n=13.8", "plant.friction.x.vs_m_s=0.02")


def _fake(set_id, contour, label, rms, peak, est=None, true=None):
    case = report.Case(set_id, contour, label, "x.yaml", "diarc", ())
    return report.CaseResult(
        case, rms, peak, (0.0, 1.0), 10, 0.0, true or [1.0] * 8, est, (0.0, 1.0), np.zeros(1), np.zeros(1)
    )


def _row(lines, start):
    rows = [line for line in lines if line.startswith(start)]
    assert len(rows) == 1, (start, rows)
    return [cell.strip() for cell in rows[0].strip("|").split("|")]


def test_table_and_acceptance_on_known_numbers():
    """Each row's paper, rig and Coulomb cells and the rig's error; fit vs validation; the ratio checks."""
    c1 = 2.63 * 1.31  # ellipse Set 1 C1 rms, +31 % off the paper's 2.63
    rig = {
        (1, "circle", "C1"): _fake(1, "circle", "C1", 2.03 * 1.10, 7.31 * 0.80),
        (1, "circle", "C2"): _fake(1, "circle", "C2", 2.00, 7.0),
        (1, "circle", "C3"): _fake(1, "circle", "C3", 2.49 * 2.03 * 1.10, 20.0),  # 2.49x C1's rms
        (1, "ellipse", "C1"): _fake(1, "ellipse", "C1", c1, 9.35 * 0.71),  # max -29 %
        (1, "ellipse", "C2"): _fake(1, "ellipse", "C2", 1.06 * c1, 8.19),  # 1.06x DARC's rms, +40 % off
        (1, "ellipse", "C3"): _fake(1, "ellipse", "C3", 2.51 * 1.06 * c1, 18.17),  # 2.51x, +31 % off 7.00
    }
    coulomb = {k: _fake(*k, 0.5, 1.5) for k in rig}
    lines = rig_report.matrix_table(rig, coulomb)
    assert _row(lines, "| circle | 1 | C1 |") == [
        "circle", "1", "C1", "2.03 / 7.31", "2.23 / 5.85", "0.50 / 1.50", "+10 / -20", "fit"
    ]  # fmt: skip
    assert _row(lines, "| ellipse | 1 | C1 |")[-2:] == ["+31 / -29", "validation"]
    assert len(lines) == 2 + len(rig)  # cells missing from the runs are left out

    checks = rig_report.acceptance(rig)
    # validation: ellipse Set 1's six numbers (circle Set 1 is the fit); the three rms miss, the three max do not
    assert checks[0] == (
        None,
        "validation numbers within +-30 % of the paper: 3 of 6; "
        "misses: ellipse 1 C1 rms +31 %, ellipse 1 C2 rms +40 %, ellipse 1 C3 rms +31 %",
    )
    verdict = {t.split(" (")[0]: ok for ok, t in checks[1:]}
    assert verdict == {
        "circle Set 1: C3 rms >= 2.5x C1's and C2's": False,
        "circle Set 1: DIARC rms <= 1.05 DARC's": True,
        "ellipse Set 1: C3 rms >= 2.5x C1's and C2's": True,
        "ellipse Set 1: DIARC rms <= 1.05 DARC's": False,
    }


def test_estimate_checks_use_the_issue_limits():
    """M within 3 %, B and Af within 10 %, dN within 0.01 V of the true values."""
    true = [0.1, 0.5, 0.5, 0.7, 0.1, 0.15, 0.05, 0.07]
    good = [0.1029, 0.5, 0.545, 0.7, 0.1, 0.15, 0.0595, 0.07]  # M1 +2.9 %, B1 +9 %, dN1 +0.0095 V
    bad = [0.1031, 0.5, 0.5, 0.7, 0.1, 0.15, 0.05, 0.07]  # M1 +3.1 %
    bad_dn = [0.1, 0.5, 0.5, 0.7, 0.1, 0.15, 0.05, 0.0595]  # dN2 -0.0105 V
    for est, ok in ((good, True), (bad, False), (bad_dn, False)):
        checks = rig_report.acceptance({(1, "circle", "C2r"): _fake(1, "circle", "C2r", 1, 1, est, true)})
        assert [c for c, t in checks if t.startswith("DIARC recommended, circle Set 1")] == [ok]


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        (None, "no such file; give a rig file"),
        ("{", "not JSON"),
        ('{"parameters": {}}', "overrides: must be a non-empty list"),
        ('{"overrides": ["plant.friction.model=lugre", 3]}', "overrides: must be a non-empty list"),
    ],
)
def test_a_bad_rig_file_is_exit_2_with_one_line_and_nothing_written(tmp_path, capsys, text, fragment):
    rig = tmp_path / "fit.json"
    if text is not None:
        rig.write_text(text)
    code, _, err = run_main(["report", "--rig", str(rig), "--out", str(tmp_path / "r"), *_sets(TINY)], capsys)
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "fit.json" in err and fragment in err, err
    assert not (tmp_path / "r").exists()


def test_a_rig_override_out_of_range_is_exit_2(tmp_path, capsys):
    rig = tmp_path / "fit.json"
    rig.write_text(json.dumps({"overrides": ["plant.friction.model=lugre", "plant.friction.x.fs_n=20"]}))
    code, _, err = run_main(["report", "--rig", str(rig), "--out", str(tmp_path / "r"), *_sets(TINY)], capsys)
    assert code == 2 and "Fs / Fc" in err, err


def _sets(overrides):
    return [arg for o in overrides for arg in ("--set", o)]


def _fake_run(seen):
    def fake_run(cases, jobs=1, progress=False):
        seen.append(list(cases))
        ideal = [c.overrides[-len(rig_report.IDEAL) :] == rig_report.IDEAL for c in cases]
        return [
            _fake(c.set_id, c.contour, c.label, 1.0 if i else 3.0, 2.0 if i else 9.0)
            for c, i in zip(cases, ideal, strict=True)
        ]

    return fake_run


SPIKES = {(label, name): (np.array([-1.0, 0.0, 1.0]), np.zeros(3)) for label in rig_report.LABELS
          for name in ("rig", "ideal")}  # fmt: skip


def test_report_runs_the_rig_twin_and_the_ideal_twin_by_default(tmp_path, capsys, monkeypatch):
    """Without flags: the matrix on the scenarios' plant (the rig plant, the default machine) and C1-C3 again on
    the ideal twin (plant.model=paper after each case's own overrides); Tables 1-2 name the plant; the section
    puts paper / rig twin / ideal twin side by side."""
    seen = []
    monkeypatch.setattr(report, "run_matrix", _fake_run(seen))
    monkeypatch.setattr(rig_report, "spike_series", lambda overrides, rig: SPIKES)
    code, _, err = run_main(["report", "--out", str(tmp_path / "r"), *_sets(TINY)], capsys)
    assert code == 0, err
    paper = report.paper_matrix(TINY)
    ideal = [report.Case(**{**c.__dict__, "overrides": (*c.overrides, *rig_report.IDEAL)}) for c in paper
             if c.label in rig_report.LABELS]  # fmt: skip
    assert seen == [paper + ideal]
    assert all(load_scenario(c.scenario_path, c.overrides).plant.model == "rig" for c in paper)
    text = (tmp_path / "r" / "report.md").read_text()
    assert "comes from the rig plant (models/rig.xml)" in text
    assert "| **rms twin, rig plant (um)** |" in text
    lines = text[text.index("## Paper, rig twin and ideal twin") :].splitlines()
    assert _row(lines, "| circle | 1 | C3 |")[3:] == ["7.33 / 21.00", "3.00 / 9.00", "1.00 / 2.00", "-59 / -57", "fit"]
    assert text.index("## Paper, rig twin and ideal twin") < text.index("## Runs")
    assert (tmp_path / "r" / rig_report.SPIKE_FILE).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads((tmp_path / "r" / "results.json").read_text())["plant"] == "rig plant (models/rig.xml)"


@pytest.mark.parametrize("flags", [["--no-ideal"], ["--set", "plant.model=paper"]])
def test_report_without_the_ideal_twin_runs_one_matrix(tmp_path, capsys, monkeypatch, flags):
    """--no-ideal, or a matrix on the ideal twin already: one matrix, no section, no rig files."""
    seen = []
    monkeypatch.setattr(report, "run_matrix", _fake_run(seen))
    code, _, err = run_main(["report", "--out", str(tmp_path / "r"), *_sets(TINY), *flags], capsys)
    assert code == 0, err
    overrides = (*TINY, *flags[1:])
    assert seen == [report.paper_matrix(overrides)]
    text = (tmp_path / "r" / "report.md").read_text()
    assert "## Paper, rig twin and ideal twin" not in text
    assert not list((tmp_path / "r").glob("rig*"))
    plant = "ideal plant" if flags[0] == "--set" else "rig plant"
    assert f"comes from the {plant}" in text


def test_report_with_rig_runs_the_calibrated_plant_beside_the_ideal_twin(tmp_path, capsys, monkeypatch):
    """--rig FILE: the matrix with FILE's overrides after each case's own (the rig twin), C1-C3 on the ideal
    twin without them; rig.json records FILE's overrides."""
    seen = []
    monkeypatch.setattr(report, "run_matrix", _fake_run(seen))
    monkeypatch.setattr(rig_report, "spike_series", lambda overrides, rig: SPIKES)
    fit = tmp_path / "fit.json"
    fit.write_text(json.dumps({"overrides": list(RIG), "parameters": {}}))
    code, _, err = run_main(["report", "--rig", str(fit), "--out", str(tmp_path / "r"), *_sets(TINY)], capsys)
    assert code == 0, err
    rigged = report.paper_matrix((*TINY, *RIG))
    ideal = [report.Case(**{**c.__dict__, "overrides": (*c.overrides, *rig_report.IDEAL)})
             for c in report.paper_matrix(TINY) if c.label in rig_report.LABELS]  # fmt: skip
    assert seen == [rigged + ideal]
    text = (tmp_path / "r" / "report.md").read_text()
    assert "rig plant (models/rig.xml), with plant overrides" in text
    assert json.loads((tmp_path / "r" / rig_report.RIG_JSON).read_text())["overrides"] == list(RIG)


@pytest.mark.parametrize("label", rig_report.LABELS)
def test_spike_runs_are_valid_with_the_shipped_windows(label):
    """With the shipped scenario's own windows (no overrides) each spike run builds: it stops 50 ms after the first
    X reversal past T + 50 ms (the circle at 2 rad/s reverses X every pi/2 s: at 5 pi/4 s after T = pi s)."""
    for plant in ((), RIG):
        built, t0 = rig_report.spike_run(label, plant)
        vx = reference(built.path, built.timing, np.array([t0 - 1e-3, t0 + 1e-3])).dq_d[:, 0]
        assert vx[0] * vx[1] < 0
        assert t0 == pytest.approx(1.25 * math.pi, abs=1e-4)
        assert built.scenario.duration_s == pytest.approx(t0 + rig_report.SPIKE_HALF_S, abs=1e-6)


@pytest.mark.slow
def test_rig_runs_against_independent_runs_and_the_reversal_spike(tmp_path, capsys):
    """Real runs: the rig column equals `run` with the rig's overrides (computed from its trace); the spike
    series sit +-50 ms around a reversal of the desired X velocity, and the rig twin's differs from the ideal's."""
    cases = report.paper_matrix(TINY, sets=(1,), contours=("circle",), labels=("C1",))
    rigged = rig_report.rig_cases(cases, RIG)
    results = report.run_matrix([*rig_report.rig_cases(cases, rig_report.IDEAL), *rigged], jobs=1)
    ideal, rig = results[:1], results[1:]
    lines = rig_report.section(ideal, rig, RIG, tmp_path / "rep", TINY)

    out = tmp_path / "run"
    argv = ["run", "no_load_circle", "--controller", "darc", *_sets((*TINY, *RIG)), "--out", str(out), "--no-plots"]
    code, _, err = run_main(argv, capsys)  # its figures are not read here
    assert code == 0, err
    table = pq.read_table(out / "trace.parquet")
    t = table.column("t_s").to_numpy()
    eps_um = np.abs(trace_column(table, "eps_c_m")[(t >= 0.02) & (t < 0.1)]) * 1e6
    rms, peak = math.sqrt(np.mean(eps_um**2)), eps_um.max()
    assert rig[0].rms_um == pytest.approx(rms, rel=2 * FLOAT32_REL)
    assert rig[0].max_um == pytest.approx(peak, rel=2 * FLOAT32_REL)
    assert abs(rig[0].rms_um - ideal[0].rms_um) > 1e-3  # the rig plant is another plant
    assert _row(lines, "| circle | 1 | C1 |")[4] == f"{rms:.2f} / {peak:.2f}"

    path = shipped("no_load_circle")
    scenario = load_scenario(path, TINY, "darc")
    series = rig_report.spike_series(TINY, RIG)
    t0 = rig_report._first_x_reversal_s(scenario, path)
    assert t0 >= 0.02 + rig_report.SPIKE_HALF_S
    built = build(scenario, path)
    vx = reference(built.path, built.timing, np.array([t0 - 1e-3, t0 + 1e-3])).dq_d[:, 0]
    assert vx[0] * vx[1] < 0  # the desired X velocity reverses there
    for label in rig_report.LABELS:
        (t_rig, e_rig), (t_c, e_c) = series[(label, "rig")], series[(label, "ideal")]
        assert t_rig[0] == pytest.approx(-50.0) and t_rig[-1] >= 49.0
        np.testing.assert_array_equal(t_rig, t_c)
        assert np.max(np.abs(e_rig - e_c)) > 0.1, label
    assert (tmp_path / "rep" / rig_report.SPIKE_FILE).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(("misses", "verdict"), [(4, True), (5, False)])
def test_validation_count_is_judged_on_the_whole_matrix(misses, verdict):
    """At least 22 of the 26 validation numbers within +-30 %: 4 misses pass, 5 fail."""
    cells = [k for k in report.PAPER_CONTOUR_UM if (k[0], k[1]) != ("circle", 1)]
    numbers = [(k, kind) for k in cells for kind in (0, 1)]
    assert len(numbers) == 26
    off = set(numbers[:misses])
    rig = {}
    for contour, set_id, label in cells:
        paper = report.PAPER_CONTOUR_UM[(contour, set_id, label)]
        value = [p * (1.31 if ((contour, set_id, label), i) in off else 1.29) for i, p in enumerate(paper)]
        rig[(set_id, contour, label)] = _fake(set_id, contour, label, *value)
    first = rig_report.acceptance(rig)[0]
    assert first[0] is verdict
    assert first[1].startswith(f"validation numbers within +-30 % of the paper: {26 - misses} of 26 (target 22 of 26)")


def test_spike_figure_titles_do_not_run_into_each_other():
    # "C2 (DIARC, paper estimator (250/150 Hz filters))" touched the neighbouring panels' titles.
    import matplotlib.pyplot as plt

    from gantry_twin.reports.rig import LABELS, spike_figure

    t = np.linspace(-50.0, 50.0, 11)
    fig = spike_figure({(label, name): (t, np.sin(t)) for label in LABELS for name in ("rig", "ideal")})
    fig.canvas.draw()
    boxes = [ax.title.get_window_extent() for ax in fig.axes]
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1 :])
    assert all(ax.title.get_window_extent().width < ax.get_window_extent().width for ax in fig.axes)
    plt.close(fig)
