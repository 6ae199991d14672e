"""LinuxCNC's semantics the twin's reader follows (docs/gcode.md): polar coordinates in G91, G90.1 arc centres,
the feed modes G93 / G95, G10 L1 tool-table writes, splines (G5, G5.1, G5.2 / G5.3).

Each expected value is computed here from LinuxCNC's documented rule (its G-code reference), independently
of the reader; tests/test_gcode_rs274.py compares whole programs with LinuxCNC's own interpreter.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from gantry_twin.gcode import GcodeError, parse_program
from gantry_twin.gcode.geometry import MoveTable
from gantry_twin.gcode.splines import SAMPLES_PER_POINT, basis, knots
from gantry_twin.gcode.tools import Tool


def ends_mm(text: str, **kwargs) -> list[tuple[float, float]]:
    """The end of every block's move (pieces of a split block left out), mm, rounded to 1 nm."""
    program = parse_program(text, name="t.ngc", **kwargs)
    return [(round(m.end_m[0] * 1e3, 6) + 0.0, round(m.end_m[1] * 1e3, 6) + 0.0) for m in program.moves if not m.piece]


def polar(radius: float, degrees: float) -> tuple[float, float]:
    a = math.radians(degrees)
    return (round(radius * math.cos(a), 6) + 0.0, round(radius * math.sin(a), 6) + 0.0)


# -- polar coordinates ---------------------------------------------------------------------------------------
def test_polar_in_g91_adds_to_the_radius_and_angle_about_the_xy_zero():
    """G91 @-1 ^30 repeated from (10, 0): a spiral about the origin, not steps from the current point."""
    text = "G1 X10 F100\nG91\n" + "G1 @-1 ^30\n" * 4
    assert ends_mm(text)[1:] == [polar(10 - k, 30 * k) for k in range(1, 5)]


def test_polar_in_g90_keeps_the_angle_or_radius_not_given():
    text = "G1 @10 ^90 F100\n@5\n^180\n"
    assert ends_mm(text) == [polar(10, 90), polar(5, 90), polar(5, 180)]


def test_polar_is_about_the_program_zero_of_the_system_and_g92():
    """The zero is the program's: the G55 offset and the G92 shift move it, rotation turns the angle."""
    text = "G55 G1 X3 Y4 F100\nG92 X0 Y0\nG91 @5 ^0\n"  # G92 at (3, 4): the current point is the zero
    with pytest.raises(GcodeError, match=r"t.ngc:3:5: @: G91 polar motion is undefined at the XY zero"):
        parse_program(text, name="t.ngc", work_offsets_mm={2: (100.0, 0.0)})
    text = "G10 L2 P1 X100 R90\nG1 X10 Y0 F100\nG91 @5 ^0\n"  # rotated 90 deg about (100, 0)
    assert ends_mm(text) == [(100.0, 10.0), (100.0, 15.0)]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("G1 @5 F100\n", "t.ngc:1:4: @: at the XY zero polar coordinates need the angle ^"),
        ("G91 G1 ^5 F100\n", "t.ngc:1:8: ^: G91 polar motion is undefined at the XY zero (no angle to add to)"),
        ("G53 G1 @5 ^3 F100\n", "t.ngc:1:8: @: polar coordinates cannot be used with G53"),
    ],
)
def test_polar_refusals_are_linuxcncs(text, message):
    with pytest.raises(GcodeError) as info:
        parse_program(text, name="t.ngc")
    assert str(info.value) == message


# -- arc centres -------------------------------------------------------------------------------------------
def test_g90_1_reads_i_j_as_the_centre_in_program_coordinates():
    """G0 X10 Y0, G90.1 G2 X30 Y0 I20 J0: the centre (20, 0), a half circle of radius 10 (the issue's case)."""
    program = parse_program("G0 X10 Y0\nG90.1 G2 X30 Y0 I20 J0 F100\nG91.1 G2 X10 Y0 I-10 J0\n")
    first, second = program.moves
    assert first.centre_m == pytest.approx((0.020, 0.0), abs=1e-15)
    assert first.sweep_rad == pytest.approx(-math.pi)
    assert second.centre_m == pytest.approx((0.020, 0.0), abs=1e-15)  # G91.1: from the start (30, 0)


def test_g90_1_centres_move_with_the_offsets_and_need_both_words():
    program = parse_program("G10 L2 P1 X5 Y5 R90\nG0 X10 Y0\nG90.1 G3 X-10 Y0 I0 J0 F100\n")
    (arc,) = program.moves
    assert arc.centre_m == pytest.approx((0.005, 0.005), abs=1e-15)  # the system's origin, turned with it
    with pytest.raises(GcodeError, match=r"t.ngc:2: J: missing: G90.1 \(absolute arc centres\) needs both I and J"):
        parse_program("G0 X10\nG90.1 G2 X30 I20 F100\n", name="t.ngc")


# -- feed modes --------------------------------------------------------------------------------------------
def test_g93_makes_each_move_take_60_over_f_seconds():
    program = parse_program("G0 X0 Y0\nG93 G1 X30 F2\nG3 X0 Y30 I-30 J0 F4\nG94 G1 X10 F600\n")
    line, arc, back = program.moves
    assert line.length_m / line.feed_m_s == pytest.approx(30.0)  # 60 / 2 s
    assert arc.length_m / arc.feed_m_s == pytest.approx(15.0)
    assert back.feed_m_s == pytest.approx(0.010)
    with pytest.raises(GcodeError, match=r"t.ngc:2: G1: G93 \(inverse time\) needs F > 0 on every feed move"):
        parse_program("G93 G1 X1 F1\nX2\n", name="t.ngc")


def test_g95_feeds_f_per_revolution_at_the_programmed_speed():
    program = parse_program("G95 S1200 G1 X10 F0.05\nG20 X1\n")
    mm, inch = program.moves
    assert mm.feed_m_s == pytest.approx(0.05e-3 * 1200 / 60)
    assert inch.feed_m_s == pytest.approx(0.05 * 25.4e-3 * 1200 / 60)  # F is in the units in force
    with pytest.raises(GcodeError, match=r"t.ngc:1:5: G1: no feed: the spindle speed S is 0"):
        parse_program("G95 G1 X10 F1\n", name="t.ngc")


# -- tool table writes -------------------------------------------------------------------------------------
def test_g10_l1_writes_the_radius_cutter_compensation_then_uses():
    square = "G0 X0 Y0\nG41 G1 X10 Y0 F100\nY10\nX0\nG40 G1 X-10 Y-10\n"
    tools = {1: Tool(1, 1, 0.002)}
    written = parse_program("G10 L1 P1 R2.5\nT1 M6\n" + square, tools=tools)
    # LinuxCNC (rs274 -g) offsets this square's corners by 2.5 mm: (7.5, 2.5), (7.5, 7.5), (0, 7.5)
    assert [m.end_m for m in written.moves][:3] == [
        pytest.approx(p, abs=1e-12) for p in ((0.0075, 0.0025), (0.0075, 0.0075), (0.0, 0.0075))
    ]
    assert tools[1].diameter_m == 0.002  # the caller's table is not written
    inch = parse_program("G20 G10 L10 P2 R0.05 X1 Z3\nG21 T2 M6\n" + square)
    assert inch.moves[0].end_m == pytest.approx((0.01 - 1.27e-3, 1.27e-3), abs=1e-12)  # a new tool, R in inches
    with pytest.raises(GcodeError, match=r"t.ngc:1: P: G10 L1 / L10 / L11 need P"):
        parse_program("G10 L1 R1\n", name="t.ngc")


# -- splines -----------------------------------------------------------------------------------------------
def _points_along(program) -> np.ndarray:
    table = MoveTable(program.moves)
    out = []
    for k in range(table.count):
        u = np.linspace(0.0, table.length[k], 40)
        out.append(table.kinematics(np.full(40, k), u, u * 0, u * 0, u * 0)[0])
    return np.concatenate(out)


def _distance_to(curve: np.ndarray, points: np.ndarray) -> np.ndarray:
    return np.min(np.hypot(points[:, None, 0] - curve[None, :, 0], points[:, None, 1] - curve[None, :, 1]), axis=1)


def test_g5_1_follows_its_quadratic_bezier_in_linuxcncs_biarcs():
    """Quadratic: B(t) = (1-t)^2 P0 + 2 t (1-t) P1 + t^2 P2, P0 the start, P1 = P0 + (I, J), P2 the end."""
    program = parse_program("G0 X0 Y0\nG5.1 X40 Y0 I20 J30 F600\n")
    moves = program.moves
    assert len(moves) == 2 * SAMPLES_PER_POINT * 3  # 4 samples per control point, a biarc between samples
    assert [m.piece for m in moves] == [True] * (len(moves) - 1) + [False]
    assert moves[-1].end_m == pytest.approx((0.040, 0.0), abs=1e-15)
    t = np.linspace(0.0, 1.0, 20001)[:, None]
    p0, p1, p2 = np.array([0.0, 0.0]), np.array([0.020, 0.030]), np.array([0.040, 0.0])
    bezier = (1 - t) ** 2 * p0 + 2 * t * (1 - t) * p1 + t**2 * p2
    assert _distance_to(bezier, _points_along(program)).max() < 2e-6  # the biarcs hug the curve within 2 um
    for a, b in zip(moves[:-1], moves[1:], strict=True):
        assert a.end_m == b.start_m


def test_g5_follows_its_cubic_and_chains_from_the_last_p_q():
    text = "G0 X0 Y0\nG5 X30 Y0 I0 J20 P0 Q20 F600\nG5 X60 Y0 P0 Q-20\nX70\n"  # G5 is not modal: X70 is a G0
    program = parse_program(text)
    ends = [m.end_m for m in program.moves if not m.piece]
    assert ends == [pytest.approx(p) for p in ((0.03, 0.0), (0.06, 0.0), (0.07, 0.0))]
    assert program.moves[-1].rapid
    program = parse_program(text.replace("X70\n", ""))  # the curves alone, for their shape
    t = np.linspace(0.0, 1.0, 20001)[:, None]

    def cubic(p0, p1, p2, p3):
        return (1 - t) ** 3 * p0 + 3 * t * (1 - t) ** 2 * p1 + 3 * t**2 * (1 - t) * p2 + t**3 * p3

    a = np.array
    first = cubic(a([0, 0]), a([0, 20]), a([30, 20]), a([30, 0])) * 1e-3
    second = cubic(a([30, 0]), a([30, -20]), a([60, -20]), a([60, 0])) * 1e-3  # I J: the last G5's -P -Q
    assert _distance_to(np.concatenate([first, second]), _points_along(program)).max() < 5e-6


def test_g5_2_nurbs_is_the_weighted_b_spline_of_its_control_points():
    """A quarter circle as a rational quadratic: (10,0) (10,10) w=1/sqrt2 (0,10); every point on radius 10."""
    w = 1 / math.sqrt(2)
    text = f"G0 X10 Y0\nG5.2 X10 Y10 P{w!r} L3 F600\nX0 Y10 P1\nG5.3\nG1 X0 Y0\n"
    program = parse_program(text)
    points = _points_along(program)[:-40]  # the NURBS's arcs, not the closing line
    assert np.abs(np.hypot(points[:, 0], points[:, 1]) - 0.010).max() < 1e-7
    assert program.moves[-2].end_m == pytest.approx((0.0, 0.010), abs=1e-15)


def test_the_basis_sums_to_one_on_linuxcncs_clamped_knots():
    knot = knots(6, 4)
    assert list(knot) == [0, 0, 0, 0, 1, 2, 3, 3, 3, 3]  # 0 k times, 1 .. n-k+1, n-k+2 k times
    for u in np.linspace(0.0, 3.0, 31):
        assert basis(float(u), 4, knot).sum() == pytest.approx(1.0)
    assert list(basis(3.0, 4, knot)) == [0, 0, 0, 0, 0, 1]  # the end is the last control point


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("G1 X1 F100\nG5.1 X5 I1\n", "t.ngc:2:1: G5.1: needs both I and J"),
        ("G1 X1 F100\nG5 X5 I1 J1 P1\n", "t.ngc:2:1: G5: needs both P and Q"),
        ("G1 X1 F100\nG5.2 X5 Y1 P1\nX6\n", "t.ngc:3:1: X: a G5.2 control point needs both X and Y"),
        ("G1 X1 F100\nG5.2 X5 Y1 P1\nG5.3\n", "t.ngc:3:1: G5.3: a NURBS of order 3 needs at least 3"),
        ("G1 X1 F100\nG5.3\n", "t.ngc:2:1: G5.3: ends a NURBS: G5.2 first"),
        ("G1 X1 F100\nG41.1 D1 G5.1 X5 I1 J1\n", "t.ngc:2:10: G5.1: a spline cannot be cut with cutter radius"),
        (f"G5 X10 Y0 I{'9' * 200} J0 P0 Q0 F100\n", "t.ngc:1:1: G5: a control point 1e+200 mm from the program's"),
        ("G1 X10 F100\nG2 X10.001 Y0 I-10 J0 P1001\n", "t.ngc:2:23: P: at most 1000 turns for an arc whose end is off"),
    ],
)
def test_spline_refusals_name_the_word(text, message):
    with pytest.raises(GcodeError) as info:
        parse_program(text, name="t.ngc")
    assert str(info.value).startswith(message), str(info.value)


# -- cutter compensation: G40 and G41 again with no move between -----------------------------------------------
def test_g41_right_after_g40_ends_the_run_where_the_tool_is_and_starts_the_next_there():
    """LinuxCNC's convert_cutter_compensation_off: the run ends at its last offset point (20 - 2, 20), and the
    next entry line starts there, not at the programmed (20, 20) (rs274 -g prints (18, 20) then (38, 22))."""
    text = "G10 L1 P1 R2\nT1 M6\nG0 X-10 Y-10\nG41 G1 X0 Y0 F100\nX20\nY20\nG40\nG41\nG1 X40 Y20\nY40\nG40 X50 Y50\n"
    moves = parse_program(text).moves
    ends = [(round(m.end_m[0] * 1e3, 9), round(m.end_m[1] * 1e3, 9)) for m in moves]
    assert ends[3:6] == [(18.0, 20.0), (38.0, 22.0), (38.0, 40.0)]
    assert moves[4].start_m == moves[3].end_m  # no gap: the tool goes on from where it stands
    arc = text.replace("G1 X40 Y20\nY40", "G3 X40 Y20 I10 J0\nG1 Y40")
    with pytest.raises(GcodeError, match=r"t.ngc:9:1: G3: the move just after G40 must be a line"):
        parse_program(arc, name="t.ngc")


def test_a_z_only_move_after_g40_is_the_exit_and_an_arc_may_follow():
    """LinuxCNC's convert_cutter_compensation_off makes the programmed point the current one: the next straight
    move, Z only here, takes the tool from its offset end (20, 2) back to the programmed (20, 0) (rs274 -g prints
    STRAIGHT_TRAVERSE(20, 0, 5)), so an arc may follow (LinuxCNC's sample gmoccapy_2_tools... does this)."""
    text = "G10 L1 P1 R2\nT1 M6\nG0 X-10 Y-10\nG41 G1 X0 Y0 F100\nX20\nG40\nG0 Z5\nX20 Y0\nG41 G3 X30 Y10 I10 J0\n"
    moves = parse_program(text + "G1 Y20\nG40 X40 Y30\n", drop_unsupported=True).moves
    exit_move = next(m for m in moves if m.line == 7)
    assert exit_move.start_m == pytest.approx((20e-3, 2e-3), abs=1e-12)
    assert exit_move.end_m == pytest.approx((20e-3, 0.0), abs=1e-12)
    assert [m.line for m in moves].count(8) == 0  # already there: no move
    zero = parse_program(text.replace("R2", "R0") + "G1 Y20\nG40 X40 Y30\n", drop_unsupported=True).moves
    assert [m.line for m in zero].count(7) == 0  # a radius of 0: G40 does nothing, the Z move stays Z only


def test_m61_sets_the_loaded_tool_that_g41_compensates_by():
    """LinuxCNC's M61 Q: the loaded tool is Q, with no tool change (its sample offsets.ngc uses it)."""
    text = "G10 L1 P1 R2\nG10 L1 P2 R1\nT2 M6\nM61 Q1\nG0 X-10 Y-10\nG41 G1 X0 Y0 F100\nX20\nG40 X30 Y-10\n"
    moves = parse_program(text).moves
    assert moves[1].end_m[1] == pytest.approx(2e-3)  # tool 1's radius 2 mm left of the X line, not tool 2's 1 mm
    with pytest.raises(GcodeError, match=r"t.ngc:1:1: M61: needs Q, the tool number now loaded"):
        parse_program("M61\n", name="t.ngc")
    cycle = parse_program("G10 L1 P1 R2\nG0 X0 Y0\nG81 X1 Y1 Z-1 R1 M61 Q1\n", drop_unsupported=True)  # rs274 runs it
    assert cycle.moves[-1].end_m == pytest.approx((1e-3, 1e-3))


def test_numbered_parameters_are_linuxcncs_and_5599_turns_debug_messages_off():
    """LinuxCNC's interpreter: #1 to #5601 (RS274NGC_MAX_PARAMETERS - 1), all writable but the tool's 5400-5413 and
    the current point's 5420-5428; #5599 (1 at the start) shows (debug, ...) while above 0 (LinuxCNC's sample
    offsets.ngc sets it; the reader refused it as past 5399)."""
    text = "(debug, a)\n#5599=0\n(debug, b)\n(print, c)\n#5599=[#5599+1]\n(debug, d #5599)\n#5601=2\nG1 X#5601 F100\n"
    program = parse_program(text)
    assert [m.split(": ", 1)[1] for m in program.messages] == ["debug: a", "print: c", "debug: d 1.000000"]
    assert program.moves[-1].end_m[0] == pytest.approx(2e-3)
    refused = [("#5410=1", "t.ngc:1:1: #5410: cannot be set"), ("#5425=1", "t.ngc:1:1: #5425: cannot be set"),
               ("#5602=1", "t.ngc:1:1: #5602: cannot be set"),
               ("G1 X#5602 F1", "t.ngc:1:5: #5602: no such parameter (numbered parameters are 1 to 5601)")]  # fmt: skip
    for line, message in refused:
        with pytest.raises(GcodeError) as info:
            parse_program(line + "\n", name="t.ngc")
        assert str(info.value).startswith(message), str(info.value)


def test_g5_and_g5_1_leave_the_motion_mode_as_it_was():
    """LinuxCNC 2.9 (rs274 -g prints the (debug, ...) lines): 10, 10, 20; G5.3 leaves no motion mode."""
    text = "G1 X1 F100\nG5.1 X5 I1 J1\n(debug, #<_motion_mode>)\nG5 X9 I1 J1 P1 Q1\n(debug, #<_motion_mode>)\n"
    program = parse_program(text + "G2 X10 Y1 R1\n(debug, #<_motion_mode>)\n")
    assert [m.rsplit(" ", 1)[-1] for m in program.messages] == ["10.000000", "10.000000", "20.000000"]
    with pytest.raises(GcodeError, match=r"t.ngc:5:1: X: an axis word without G0, G1, G2, G3 or a cycle in force"):
        parse_program("G1 X1 F100\nG5.2 X5 Y1 P1\nX6 Y2 P1\nG5.3\nX7\n", name="t.ngc")
