"""A planned program in the loop: a gcode contour in a scenario, and the circle program against the paper's."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from gantry_twin.controllers import create
from gantry_twin.gcode import read_program
from gantry_twin.gcode.part_error import part_error
from gantry_twin.gcode.planner import plan_program
from gantry_twin.gcode.sampling import Plan
from gantry_twin.loop.simulate import simulate
from gantry_twin.paths.contours import TimingLaw, circle, reference
from gantry_twin.plant.model import Plant
from gantry_twin.scenario import ScenarioError, build, load_scenario

PROGRAMS = Path(__file__).resolve().parents[1] / "programs"


def test_a_scenario_runs_a_program_relative_to_its_file(tmp_path):
    shutil.copy(PROGRAMS / "polygon_g64.ngc", tmp_path / "part.ngc")
    scenario_file = tmp_path / "part.yaml"
    scenario_file.write_text(
        "contour:\n  type: gcode\n  file: part.ngc\n  limits: {velocity_m_s: [0.5, 0.5], "
        "acceleration_m_s2: [20, 5], jerk_m_s3: [1000, 200]}\n"
    )
    built = build(load_scenario(scenario_file), str(scenario_file))
    assert isinstance(built.path, Plan)
    # the run lasts the plan, in whole samples (the last one at or after the plan's end)
    assert built.path.duration_s <= built.duration_s < built.path.duration_s + built.plant.timestep_s + 1e-12
    assert built.path.options.limits.acceleration_m_s2 == (20.0, 5.0)
    assert built.timing == TimingLaw(1.0)
    ref = reference(built.path, built.timing, np.array([0.0, 1.0]))
    assert ref.q_d[0] == pytest.approx((0.0, -0.15)) and np.all(ref.dq_d[0] == 0.0)


def test_the_runs_scenario_names_the_programs_files_by_their_absolute_paths(tmp_path):
    """The run's scenario.yaml finds the program, its tool table and subroutine directories from anywhere (compare
    reads and plans it again from the run's directory; a relative tool table was looked for there)."""
    (tmp_path / "subs").mkdir()
    (tmp_path / "subs" / "side.ngc").write_text("o<side> sub\nG1 X10 Y0 F600\no<side> endsub\n")
    (tmp_path / "part.ngc").write_text("G0 X0 Y-5\nT1 M6\nG41 G1 X0 Y0 F600\no<side> call\nG40 G1 X20 Y-5\nM2\n")
    (tmp_path / "tools.tbl").write_text("T1 P1 D2.0\n")
    scenario_file = tmp_path / "part.yaml"
    scenario_file.write_text("contour: {type: gcode, file: part.ngc, tool_table: tools.tbl, subroutine_path: [subs]}\n")
    contour = build(load_scenario(scenario_file), str(scenario_file)).scenario.contour
    assert contour.file == str(tmp_path / "part.ngc") and contour.tool_table == str(tmp_path / "tools.tbl")
    assert contour.subroutine_path == [str(tmp_path / "subs")]
    elsewhere = tmp_path / "run"
    elsewhere.mkdir()
    assert contour.plan(elsewhere).program.moves[1].end_m[1] == pytest.approx(1e-3)  # tool 1's radius, to the left


def test_a_bad_program_is_a_scenario_error_naming_its_line(tmp_path):
    (tmp_path / "part.ngc").write_text("G1 X1 F100\nG6 X2\n")
    scenario_file = tmp_path / "part.yaml"
    scenario_file.write_text("contour: {type: gcode, file: part.ngc}\n")
    with pytest.raises(ScenarioError, match=r"contour.file: .*part.ngc:2:1: G6: unsupported G code$"):
        build(load_scenario(scenario_file), str(scenario_file))


def test_the_circle_program_gives_the_papers_contour_error():
    """The circle at F24000 from rest, DIARC, one lap at constant speed, against the paper's circle (5.1) from
    rest: the planner adds nothing on a circle (G2 runs the mirror image in X of the paper's direction)."""
    plan = plan_program(read_program(PROGRAMS / "circle.ngc"))
    trace = simulate(Plant(), plan, TimingLaw(1.0), create("diarc"), plan.duration_s)
    # The same lap of both runs, well after both starts (the plan reaches F in 0.07 s, the paper's ramp takes 0.5 s).
    lap = (trace.t_s >= 2.0) & (trace.t_s < 2.0 + math.pi)
    paper = simulate(Plant(), circle(), TimingLaw(2.0, "rest", 0.5), create("diarc"), 2.1 + math.pi)
    paper_lap = (paper.t_s >= 2.0) & (paper.t_s < 2.0 + math.pi)
    assert np.allclose(np.linalg.norm(plan.sample(trace.t_s[lap]).v_m_s, axis=1), 0.4)
    rms, paper_rms = (np.sqrt(np.mean(t.eps_c_m[w] ** 2)) for t, w in ((trace, lap), (paper, paper_lap)))
    peak, paper_peak = (np.abs(t.eps_c_m[w]).max() for t, w in ((trace, lap), (paper, paper_lap)))
    assert rms == pytest.approx(paper_rms, rel=0.05)
    assert peak == pytest.approx(paper_peak, rel=0.05)
    # On the circle the part error is eps_c's magnitude (the planned path is the programmed one).
    part = part_error(plan, trace.t_s[lap], trace.q_m[lap])
    assert part.distance_m == pytest.approx(np.abs(trace.eps_c_m[lap]), abs=1e-8)


@pytest.mark.parametrize("name", ["polygon_g61.ngc", "polygon_g64.ngc"])
def test_sharp_corners_run_in_the_loop(name):
    """Stops with the task frame turning in place and blends at low speed: the loop stays well behaved."""
    plan = plan_program(read_program(PROGRAMS / name))
    trace = simulate(Plant(), plan, TimingLaw(1.0), create("diarc"), plan.duration_s)
    part = part_error(plan, trace.t_s, trace.q_m)
    assert np.all(np.isfinite(trace.eps_c_m)) and part.max_m < 100e-6
    assert np.abs(trace.q_m[-1] - plan.moves[-1].end_m).max() < 50e-6  # it ends at the last point (settling)
