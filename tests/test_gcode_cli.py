"""`gantry-twin run part.ngc`: a program runs in the default scenario; summary.json's part error is the
distance of the recorded positions to the programmed geometry, recomputed here from trace.parquet."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from gantry_twin.cli import app as cli
from gantry_twin.gcode import PlanOptions, plan_program, read_program
from gantry_twin.gcode.part_error import distance_to_program

PROGRAMS = Path(__file__).resolve().parents[1] / "programs"


def test_a_program_runs_and_its_part_error_is_the_traces_distance_to_the_program(tmp_path, capsys):
    program = PROGRAMS / "polygon_g61.ngc"
    assert cli.main(["run", str(program), "--no-plots", "--out", str(tmp_path / "r")]) == 0
    out = capsys.readouterr().out
    assert out.startswith("polygon_g61 with diarc") and "part error (to the programmed lines and arcs)" in out
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    part = summary["part_error"]
    table = pq.read_table(tmp_path / "r" / "trace.parquet")
    t = table["t_s"].to_numpy()
    q = np.stack([table["x_m"].to_numpy(), table["y_m"].to_numpy()], axis=1)
    plan = plan_program(read_program(program), PlanOptions())
    assert summary["duration_s"] == pytest.approx(plan.duration_s, abs=2e-4)  # the run lasts its plan
    d = distance_to_program(plan, plan.sample(t).move, q)
    measured = d[np.isfinite(d)]
    assert part["max_um"] == pytest.approx(1e6 * measured.max(), rel=1e-12)
    assert part["rms_um"] == pytest.approx(1e6 * np.sqrt(np.mean(measured**2)), rel=1e-12)
    assert part["corners"] == len(part["worst_corners"]) > 0
    assert summary["contour_error_um"]["window_s"] == [0.0, summary["duration_s"]]  # the whole program


def test_a_bad_program_is_one_line_file_line_word(tmp_path, capsys):
    bad = tmp_path / "bad.ngc"
    bad.write_text("G21\nG1 X10 Y0\n")
    assert cli.main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"gantry-twin: error: {bad}:2:1: G1: no feed: F must be given before the first feed move"]
    assert not (tmp_path / "o").exists()


def test_rapid_moves_are_left_out_of_the_contour_error(tmp_path, capsys):
    """summary.json's contour error of a program covers its feed moves only: recomputed here from trace.parquet
    over the window's samples outside the plan's G0 moves; with the rapids' samples it would differ."""
    program = tmp_path / "two_cuts.ngc"
    program.write_text("G17 G21 G90 G61\nG1 X50 Y0 F6000\nG0 X-100 Y80\nG1 X-40 Y80 F6000\nM2\n")
    assert cli.main(["run", str(program), "--no-plots", "--out", str(tmp_path / "r")]) == 0
    capsys.readouterr()
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    table = pq.read_table(tmp_path / "r" / "trace.parquet")
    t = table["t_s"].to_numpy()
    eps_um = np.abs(table["eps_c_m"].to_numpy().astype(float)) * 1e6
    plan = plan_program(read_program(program), PlanOptions())
    rapid = np.zeros(t.shape, dtype=bool)
    for k, move in enumerate(plan.moves):
        if move.rapid:
            rapid |= (t >= plan.t0_s[k]) & (t < plan.end_s[k])
    assert rapid.any()
    a, b = summary["contour_error_um"]["window_s"]
    feed = (t >= a) & (t < b) & ~rapid
    assert summary["contour_error_um"]["max"] == pytest.approx(eps_um[feed].max(), rel=1e-6)
    assert summary["contour_error_um"]["rms"] == pytest.approx(np.sqrt(np.mean(eps_um[feed] ** 2)), rel=1e-6)
    every = (t >= a) & (t < b)
    with_rapids = np.sqrt(np.mean(eps_um[every] ** 2))
    assert abs(with_rapids / summary["contour_error_um"]["rms"] - 1.0) > 0.05  # the rapids' error, left out
    assert "contour_error_per_period_um" not in summary  # a program has no lap
