"""The paper-reproduction report (gantry_twin.reports.paper): the matrix, its numbers, its findings."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pyarrow.parquet as pq
import pytest

from gantry_twin.plant.model import THETA_NAMES, Plant
from gantry_twin.reports import paper as report
from gantry_twin.reports import paper_figures

from .helpers import FLOAT32_REL, deviation_pct, run_main, spec_theta, trace_column

TINY = ("duration_s=0.1", "window_s=[0.02, 0.1]", "estimates_window_s=[0.05, 0.1]")


def test_paper_matrix_has_16_paper_runs_and_4_recommended():
    cases = report.paper_matrix(TINY)
    labels = [(c.set_id, c.contour, c.label) for c in cases]
    assert len(cases) == 20 and len(set(labels)) == 20
    assert not [k for k in labels if k[0] == 3 and k[2] in ("C3", "C2r")]
    assert sum(k[2] == "C2r" for k in labels) == 4


#: The tiny matrix's runs as the paper defines its columns (C1 DARC, C2 DIARC with the paper's estimator,
#: C2r DIARC with the recommended one; Set 1 no load, Set 3 step disturbance): key -> (scenario, controller, --set).
TINY_RUNS = {
    "set1_circle_C1": ("no_load_circle", "darc", ()),
    "set1_circle_C2": ("no_load_circle", "diarc", ("controller.options.estimator=paper",)),
    "set1_circle_C2r": ("no_load_circle", "diarc", ("controller.options.estimator=recommended",)),
    "set3_circle_C1": ("step_disturbance_circle", "darc", ()),
    "set3_circle_C2": ("step_disturbance_circle", "diarc", ("controller.options.estimator=paper",)),
}


def _independent_numbers(tmp_path, capsys) -> dict[str, dict]:
    """Each tiny-matrix run done again with `run`, its numbers computed from trace.parquet with plain numpy."""
    numbers = {}
    for key, (scenario, controller, extra) in TINY_RUNS.items():
        out = tmp_path / "independent" / key
        sets = [arg for override in (*TINY, *extra) for arg in ("--set", override)]
        argv = ["run", scenario, "--controller", controller, *sets, "--out", str(out), "--no-plots"]  # not read here
        code, _, err = run_main(argv, capsys)
        assert code == 0, err
        table = pq.read_table(out / "trace.parquet")
        t = table.column("t_s").to_numpy()
        eps_um = np.abs(trace_column(table, "eps_c_m")[(t >= 0.02) & (t < 0.1)]) * 1e6
        in_estimates_window = (t >= 0.05) & (t < 0.1)
        theta = [trace_column(table, f"theta_hat_{n}")[in_estimates_window] for n in THETA_NAMES]
        numbers[key] = {
            "steps": t.size,
            "rms_um": math.sqrt(np.mean(eps_um**2)),
            "max_um": eps_um.max(),
            "estimates": np.array([values.mean() for values in theta]),
            # how far float32 rounding can move each mean: 2**-24 of the mean magnitude (and float64 arithmetic)
            "estimates_tolerance": np.array([2 * FLOAT32_REL * np.abs(values).mean() for values in theta]),
            "distrust": {
                n: f"not trusted: {e['why']}"
                for n, e in json.loads((out / "summary.json").read_text()).get("estimates", {}).items()
                if e.get("trustworthy") is False
            },
        }
    return numbers


def _section(text: str, heading: str) -> str:
    """The Markdown from the heading starting with ``heading`` to the next heading of its level."""
    start = text.index(heading)
    end = text.find("\n## ", start + len(heading))
    return text[start : end if end >= 0 else None]


def _row_cells(text: str, row_start: str) -> list[str]:
    """The cells after the label of the one Markdown table row starting with row_start."""
    rows = [line for line in text.splitlines() if line.startswith(row_start)]
    assert len(rows) == 1, (row_start, rows)
    return [cell.strip() for cell in rows[0].strip("|").split("|")[1:]]


def test_signed_pct_never_says_minus_zero():
    assert report.signed_pct(-0.04) == "0.0 %" and report.signed_pct(0.0) == "0.0 %"
    assert report.signed_pct(-0.06) == "-0.1 %" and report.signed_pct(2.0) == "+2.0 %"


def test_provenance_line_names_version_date_command_and_wall_time():
    line = report.provenance("gantry-twin report --workers 2", 12.4, "1.2.3", now_s=0.0)
    assert line == (
        "Made by gantry-twin 1.2.3 on 1970-01-01 00:00:00 UTC with `gantry-twin report --workers 2` "
        "in 12 s of wall time."
    )


def test_report_on_a_tiny_matrix(tmp_path, capsys):
    """The report's numbers (results.json, Tables 1 and 3, the runs table) against the same runs done with
    `run` and computed from their traces, estimates judged against the reference machine."""
    cases = report.paper_matrix(TINY, sets=(1, 3), contours=("circle",), labels=("C1", "C2", "C2r"))
    assert len(cases) == 5
    res = report.run_matrix(cases, jobs=2)
    assert [r.case for r in res] == cases
    path = report.write_report(res, tmp_path / "rep", TINY, made_by="Made by gantry-twin x")
    text = path.read_text()
    assert text.splitlines()[2] == "Made by gantry-twin x" and "-0.0 %" not in text
    checks = json.loads((tmp_path / "rep" / "results.json").read_text())["findings"]
    assert f"{sum(c['pass'] for c in checks)} of {len(checks)} findings hold." in text
    for heading in ("Table 1", "Table 2", "Table 3", "Table 4", "after running the gantry for one period"):
        assert heading in text
    assert "| rms paper (um) | 2.03 | 1.99 | 7.33 |" in text
    pngs = sorted(p.name for p in (tmp_path / "rep").glob("*.png"))
    assert pngs == ["fig2_set3_circle_contour_error.png", "fig4_set1_y_estimates.png"]
    for name in pngs:
        assert (tmp_path / "rep" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    expected = _independent_numbers(tmp_path, capsys)
    # Sets 1 and 3 carry no load; the default machine (the rig plant): M from the masses (tests/helpers.py), B, Af,
    # dN the rig's (checked against an independent fit in tests/test_rig_plant.py).
    truth = [*spec_theta(0.0)[:2], *Plant.shipped("rig").true_parameters()[2:]]
    runs = {run["key"]: run for run in json.loads((tmp_path / "rep" / "results.json").read_text())["runs"]}
    assert set(runs) == set(TINY_RUNS)
    for key, want in expected.items():
        got = runs[key]
        assert got["steps"] == want["steps"] == 500, key
        assert got["rms_um"] == pytest.approx(want["rms_um"], rel=2 * FLOAT32_REL), key
        assert got["max_um"] == pytest.approx(want["max_um"], rel=2 * FLOAT32_REL), key
        assert np.all(np.abs(np.subtract(got["estimates"], want["estimates"])) <= want["estimates_tolerance"]), key
        np.testing.assert_allclose(got["true_theta"], truth, rtol=1e-12, atol=1e-15, err_msg=key)
        assert got["not_trusted"] == want["distrust"], key  # the verdicts `run` gives the same run
        row = _row_cells(_section(text, "## Runs"), f"| {key} |")
        assert row[:3] == ["500", f"{want['rms_um']:.3f}", f"{want['max_um']:.3f}"], key
    # Table 1 (circle): columns Set 1 C1 C2 C3, Set 2 C1 C2 C3, Set 3 C1 C2; runs not in the matrix show "-".
    columns = ["set1_circle_C1", "set1_circle_C2", None, None, None, None, "set3_circle_C1", "set3_circle_C2"]
    for what in ("rms", "max"):
        cells = [f"**{expected[key][f'{what}_um']:.2f}**" if key else "**-**" for key in columns]
        assert _row_cells(_section(text, "## Table 1:"), f"| **{what} twin (um)** |") == cells
    # Table 3 (Set 1): each estimate with its deviation from the reference value.
    for name, key in (
        ("DIARC paper settings", "set1_circle_C2"),
        ("DIARC recommended", "set1_circle_C2r"),
        ("DARC", "set1_circle_C1"),
    ):
        estimates = expected[key]["estimates"]
        cells = [f"{estimates[i]:.4f} ({report.signed_pct(deviation_pct(estimates[i], truth[i]))})" for i in range(6)]
        row = _row_cells(_section(text, "## Table 3:"), f"| {name}: circle |")
        assert [c.removesuffix(f" {report.DISTRUST_MARK}") for c in row] == cells, name
        # an estimate is marked exactly when its run's summary.json would not trust it, with the reason below
        distrust = runs[key]["not_trusted"]
        marked = [report.THETA_NAMES[i] for i, c in enumerate(row) if c.endswith(report.DISTRUST_MARK)]
        assert marked == [n for n in report.THETA_NAMES[:6] if n in distrust], name
        for n in marked:
            assert f"- {name}, circle: {n} {distrust[n]}" in text


def _fake(set_id, contour, label, rms, peak, est=None, true=None):
    case = report.Case(set_id, contour, label, "x.yaml", "diarc", ())
    return report.CaseResult(
        case, rms, peak, (0.0, 1.0), 10, 0.0, true or [1.0] * 8, est, (0.0, 1.0), np.zeros(1), np.zeros(1)
    )


def test_findings_apply_the_issue_thresholds():
    rows = [
        _fake(1, "circle", "C1", 1.0, 2.0),
        _fake(1, "circle", "C2", 1.39, 2.0),
        _fake(1, "circle", "C3", 2.7, 5.0),
        _fake(3, "circle", "C1", 3.9, 6.0),
        _fake(3, "circle", "C2", 4.1, 5.9),
        _fake(1, "circle", "C2r", 1.0, 1.0, est=[1.049, 0.96, 1, 1, 1, 1, 5, 5]),
        _fake(2, "circle", "C2r", 1.0, 1.0, est=[1.0, 1.0, 1, 1, 1, 0.94, 1, 1]),
    ]
    got = {
        text.split(" (")[0]: ok
        for ok, text in report.findings({(r.case.set_id, r.case.contour, r.case.label): r for r in rows})
    }
    assert got["circle Set 1: C1 and C2 rms within 40 % of each other"] is True
    assert got["circle Set 1: C3 rms at least twice C1's and C2's"] is False  # 2.7 < 2 x 1.39
    assert got["circle C1: Set 3 max at least 3x Set 1's"] is True
    assert got["circle C2: Set 3 max at least 3x Set 1's"] is False
    assert got["circle C1: Set 3 rms below 4 um"] is True
    assert got["circle C2: Set 3 rms below 4 um"] is False
    assert got["Set 1: DIARC recommended estimates of M, B, Af within 5 %"] is True  # dN is not judged
    assert got["Set 2: DIARC recommended estimates of M, B, Af within 5 %"] is False  # Af2 -6 %


def _with_series(result, t_s, eps_um, theta=None):
    result.t_eps_s, result.eps_c_um = t_s, eps_um
    if theta is not None:
        result.t_theta_s, result.theta_hat = t_s, theta
    return result


def test_figures_share_one_y_scale_and_label_every_axis_with_a_unit():
    """Fig. 3 draws C1..C3 on one y scale (the paper's comparison); every axis label names its unit in brackets;
    an estimate plot shows the true value inside its y range."""
    t = np.linspace(0.0, 2.0, 200)
    true = [0.12, 0.5, 0.5, 0.7, 0.1, 0.15, 0.0, 0.0]
    theta = np.tile(true, (t.size, 1)) + 0.01 * np.outer(np.sin(t), np.ones(8)) + 0.03  # all above the truth
    results = [
        _with_series(_fake(2, "ellipse", "C1", 1.0, 2.0), t, 2.0 * np.sin(t)),
        _with_series(_fake(2, "ellipse", "C2", 1.0, 4.0), t, 4.0 * np.cos(t)),
        _with_series(_fake(2, "ellipse", "C3", 1.0, 15.0), t, -15.0 * t / 2.0),
        _with_series(_fake(1, "circle", "C2", 1.0, 2.0, est=true, true=true), t, np.sin(t), theta),
    ]
    names = {label: c[2] for label, c in report.CONTROLLERS.items()}
    made = paper_figures.figures({(r.case.set_id, r.case.contour, r.case.label): r for r in results}, names)
    by_name = {name: fig for fig, name, _ in made}
    assert set(by_name) == {"fig3_set2_ellipse_contour_error.png", "fig4_set1_y_estimates.png"}
    limits = [ax.get_ylim() for ax in by_name["fig3_set2_ellipse_contour_error.png"].axes]
    assert len(limits) == 3 and all(lim == limits[0] for lim in limits)
    assert limits[0][0] <= -15.0 and limits[0][1] >= 4.0
    for fig in by_name.values():
        labels = [a.get_ylabel() for a in fig.axes] + [a.get_xlabel() for a in fig.axes if a.get_xlabel()]
        assert labels and all(re.search(r"\[[^\]]+\]$", label) for label in labels), labels
    for fig in by_name.values():  # legends below the panels: in a panel one covered Fig. 5's M1 estimate
        fig.canvas.draw()
        assert all(ax.get_legend() is None for ax in fig.axes)
        (legend,) = fig.legends
        assert not any(legend.get_window_extent().overlaps(ax.get_tightbbox()) for ax in fig.axes)
    for ax, j in zip(by_name["fig4_set1_y_estimates.png"].axes, (1, 3, 5, 7), strict=True):
        lo, hi = ax.get_ylim()
        span = theta[:, j].max() - true[j]
        assert lo <= true[j] - 0.09 * span and theta[:, j].max() + 0.09 * span <= hi, (j, lo, hi)


def test_the_matrix_and_a_sweep_share_the_one_batch_runner(monkeypatch):
    """A two-point matrix runs through sweep.engine.run_batch, the runner `gantry-twin sweep` uses; its results
    come back in case order and equal run_case's in this process."""
    from gantry_twin.sweep import driver, engine

    assert driver.run_batch is engine.run_batch  # the sweep's runner
    calls = []
    real = engine.run_batch

    def counting(function, arguments, *args, **kwargs):
        calls.append((function, len(arguments)))
        yield from real(function, arguments, *args, **kwargs)

    monkeypatch.setattr(engine, "run_batch", counting)
    cases = report.paper_matrix(TINY, sets=(1,), contours=("circle",), labels=("C1", "C2"))
    res = report.run_matrix(cases, jobs=1)
    assert calls == [(report.run_case, 2)]
    assert [r.case for r in res] == cases
    for case, got in zip(cases, res, strict=True):
        assert got.rms_um == report.run_case(case).rms_um
