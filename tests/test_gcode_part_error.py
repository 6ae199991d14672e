"""The part error (gantry_twin.gcode.part_error) against a brute-force distance to the programmed lines and arcs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gantry_twin.gcode import parse_program, read_program
from gantry_twin.gcode.part_error import part_error
from gantry_twin.gcode.planner import plan_program
from tests.test_gcode_planner import distance_to_moves

PROGRAMS = Path(__file__).resolve().parents[1] / "programs"


@pytest.mark.parametrize("name", ["polygon_g64.ngc", "rounded_rectangle.ngc"])
def test_the_part_error_is_the_distance_to_the_programmed_geometry(name):
    plan = plan_program(read_program(PROGRAMS / name))
    rng = np.random.default_rng(7)
    t = np.sort(rng.uniform(0.0, plan.duration_s, 400))
    q = plan.sample(t).q_m + rng.normal(0.0, 50e-6, (len(t), 2))  # an "actual" path 50 um off the plan
    result = part_error(plan, t, q)
    feed = [m for m in plan.moves if not m.rapid]
    brute = distance_to_moves(q, feed)
    assert result.distance_m == pytest.approx(brute, abs=1e-9)
    assert result.max_m == pytest.approx(brute.max(), abs=1e-9)


def test_the_planned_path_is_within_p_of_the_part_and_on_it_in_g61():
    g64 = plan_program(read_program(PROGRAMS / "polygon_g64.ngc"))
    t = np.arange(0.0, g64.duration_s, 2e-4)
    result = part_error(g64, t, g64.sample(t).q_m)
    assert 0.5e-5 < result.max_m <= 1e-5 + 1e-9  # the blends use their tolerance, no more
    g61 = plan_program(read_program(PROGRAMS / "polygon_g61.ngc"))
    t = np.arange(0.0, g61.duration_s, 2e-4)
    result = part_error(g61, t, g61.sample(t).q_m)
    assert result.max_m <= 1e-9
    assert len(result.corners) == len(g61.moves) - 1
    assert all(c.kind == "stop" and c.speed_m_s <= 1e-5 and c.max_m <= 1e-9 for c in result.corners)
    assert result.cycle_time_s == g61.duration_s


def test_blocks_report_time_and_feed():
    plan = plan_program(parse_program("G0 X-200 Y0\nG1 X200 F24000\nG1 Y100 F12000\nM30"))
    t = np.arange(0.0, plan.duration_s, 2e-4)
    result = part_error(plan, t, plan.sample(t).q_m)
    first, second = result.blocks
    assert first.line == 2 and second.line == 3
    assert first.feed_programmed_m_s == pytest.approx(0.4)
    assert 0.35 < first.feed_achieved_m_s < 0.4 and 0.0 < second.feed_achieved_m_s < 0.2
    assert first.time_s + second.time_s == pytest.approx(plan.duration_s, abs=1e-3)
    (corner,) = result.corners
    assert corner.kind == "blend" and corner.speed_m_s > 0.001
    assert corner.point_m == pytest.approx((0.2, 0.0))


def test_rapids_are_left_out():
    plan = plan_program(read_program(PROGRAMS / "bracket.ngc"))
    t = np.arange(0.0, plan.duration_s, 1e-3)
    q = plan.sample(t).q_m + 1e-3  # 1.4 mm off everywhere
    result = part_error(plan, t, q)
    rapid_rows = np.array([plan.moves[k].rapid for k in plan.sample(t).move])
    assert np.isnan(result.distance_m[rapid_rows]).all() and np.isfinite(result.distance_m[~rapid_rows]).all()
    assert len(result.blocks) == sum(not m.rapid for m in plan.moves)
