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
    assert err == [f"gantry-twin: error: {bad}:2: G1: no feed: F must be given before the first feed move"]
    assert not (tmp_path / "o").exists()
