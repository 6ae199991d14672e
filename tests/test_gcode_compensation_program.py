"""Cutter radius compensation through the reader, the tool table, the scenario and the command line: a G42 square
cut outside with a 3 mm tool (docs/gcode.md, "Cutter radius compensation")."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gantry_twin.cli import main
from gantry_twin.gcode import GcodeError, parse_program
from gantry_twin.gcode.tools import read_tool_table
from gantry_twin.scenario import load_scenario, shipped

SQUARE = """(a 20 mm square cut outside: G42 going counter-clockwise puts the tool right of the path, outside)
G21 G90 G17
T1 M6
G0 X-10 Y-5
G42 G1 X0 Y0 F600
X20
Y20
X0
Y0
G40 G0 X-10 Y-5
M2
"""
TABLE = "T1 P1 D3.0 ;a 3 mm end mill\n"


def _expected_square_mm(side_mm: float, r_mm: float) -> list[tuple]:
    """The tool centre around the square's four sides, computed here: each side offset by r outwards, and at each
    convex corner an arc of radius r about the corner, counter-clockwise (a quarter turn)."""
    corners = [(0.0, 0.0), (side_mm, 0.0), (side_mm, side_mm), (0.0, side_mm)]
    out = []
    for k in range(4):
        (x0, y0), (x1, y1) = corners[k], corners[(k + 1) % 4]
        ux, uy = (x1 - x0) / side_mm, (y1 - y0) / side_mm
        nx, ny = uy, -ux  # right of the direction of travel: outside for a counter-clockwise square
        out.append(("line", (x0 + r_mm * nx, y0 + r_mm * ny), (x1 + r_mm * nx, y1 + r_mm * ny)))
        if k < 3:  # the last corner is where the exit move leaves
            vx, vy = (corners[(k + 2) % 4][0] - x1) / side_mm, (corners[(k + 2) % 4][1] - y1) / side_mm
            out.append(("arc", (x1 + r_mm * nx, y1 + r_mm * ny), (x1 + r_mm * vy, y1 - r_mm * vx), (x1, y1)))
    return out


def _shape(program) -> list[tuple]:
    shapes = []
    for m in program.items:
        if m.rapid:
            continue
        mm = tuple(1e3 * c for c in m.start_m), tuple(1e3 * c for c in m.end_m)
        if m.kind == "line":
            shapes.append(("line", *mm))
        else:
            shapes.append(("arc", *mm, tuple(1e3 * c for c in m.centre_m)))
    return shapes


def _assert_same(got: list[tuple], wanted: list[tuple]) -> None:
    assert [g[0] for g in got] == [w[0] for w in wanted]
    for g, w in zip(got, wanted, strict=True):
        np.testing.assert_allclose(np.array(g[1:]), np.array(w[1:]), atol=1e-9)


def test_a_g42_square_with_a_3_mm_tool_is_the_square_offset_by_1_5_mm_with_1_5_mm_arcs(tmp_path):
    (tmp_path / "tools.tbl").write_text(TABLE)
    program = parse_program(SQUARE, name="sq.ngc", tools=read_tool_table(tmp_path / "tools.tbl"))
    feed = _shape(program)
    # The entry move from the start (-10, -5) to (0, 0) ends offset by r square to itself, and its corner with the
    # first side (a turn right, concave on the right) is the intersection of the two offset lines, computed here.
    d = np.array([10.0, 5.0]) / math.hypot(10.0, 5.0)
    right = np.array([d[1], -d[0]])
    t = (-1.5 - 1.5 * right[1]) / d[1]  # where the entry's offset line meets y = -1.5
    corner = 1.5 * right + t * d
    wanted = _expected_square_mm(20.0, 1.5)
    wanted[0] = ("line", tuple(corner), wanted[0][2])
    assert feed[0][0] == "line" and np.allclose(feed[0][1], (-10.0, -5.0)) and np.allclose(feed[0][2], corner)
    _assert_same(feed[1:], wanted)
    for arc in (m for m in program.items if m.kind == "arc"):
        assert math.isclose(arc.radius_m, 1.5e-3, rel_tol=1e-12)
        assert math.isclose(arc.sweep_rad, math.pi / 2, rel_tol=1e-9)  # a quarter turn, counter-clockwise
    # The programmed outline is kept as it was written, for the figures.
    outline = [m for m in program.programmed_moves if not m.rapid]
    assert [tuple(round(c * 1e3, 9) for c in m.end_m) for m in outline[1:5]] == [(20, 0), (20, 20), (0, 20), (0, 0)]


def test_the_scenarios_tools_give_the_table_s_path_and_a_missing_tool_is_named(tmp_path):
    (tmp_path / "sq.ngc").write_text(SQUARE)
    (tmp_path / "tools.tbl").write_text(TABLE)
    base = [f"contour={{type: gcode, file: {json.dumps(str(tmp_path / 'sq.ngc'))}}}"]
    by_table = load_scenario(shipped("no_load_circle"), [*base, f"contour.tool_table={tmp_path / 'tools.tbl'}"])
    by_list = load_scenario(shipped("no_load_circle"), [*base, "contour.tools={1: 3.0}"])
    assert _shape(by_table.contour.read()) == _shape(by_list.contour.read())
    with pytest.raises(GcodeError, match=r"sq.ngc:5: G42: tool 1 is not in the tool table \(no tool table was given"):
        load_scenario(shipped("no_load_circle"), base).contour.read()


def test_validate_with_a_tool_table_reaches_the_tool_centre_s_extent(tmp_path, capsys):
    (tmp_path / "sq.ngc").write_text(SQUARE)
    (tmp_path / "tools.tbl").write_text(TABLE)
    assert main(["validate", str(tmp_path / "sq.ngc"), "--tool-table", str(tmp_path / "tools.tbl")]) == 0
    out = capsys.readouterr().out
    assert "extent X: -10.000 .. 21.500 mm" in out and "extent Y: -5.000 .. 21.500 mm" in out  # 20 + 1.5
    assert main(["validate", str(tmp_path / "sq.ngc"), "--tool-table", str(tmp_path / "none.tbl")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none.tbl" in err[0], err
