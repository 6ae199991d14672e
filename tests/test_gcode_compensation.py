"""Cutter radius compensation (gantry_twin.gcode.compensation) against the path built independently.

The expected tool-centre paths are constructed here from the rules in LinuxCNC's documentation (offset
lines and arcs by the radius, arcs of the radius around convex corners, the offsets' intersection at
concave ones), with vectors, a linear solve and the quadratic of a line and a circle, not with the module's
angle formulas.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from gantry_twin.gcode import GcodeError
from gantry_twin.gcode.compensation import compensate, compensate_blocks
from gantry_twin.gcode.geometry import Move, MoveTable

MM = 1e-3
R = 1.5 * MM  # a 3 mm tool
TOL = 1e-12  # m


def line(a, b, number=1, rapid=False) -> Move:
    """A line between two points in mm."""
    feed = math.inf if rapid else 0.1
    return Move("line", (a[0] * MM, a[1] * MM), (b[0] * MM, b[1] * MM), feed, rapid, number)


def arc(a, b, centre, ccw, number=1, turns=1) -> Move:
    """An arc between two points on the circle about ``centre`` (mm), counter-clockwise or not."""
    a0 = math.atan2(a[1] - centre[1], a[0] - centre[0])
    a1 = math.atan2(b[1] - centre[1], b[0] - centre[0])
    sweep = ((a1 - a0) if ccw else (a0 - a1)) % (2 * math.pi)
    sweep = (sweep if sweep > 1e-12 else 2 * math.pi) + 2 * math.pi * (turns - 1)
    m = Move("arc", (a[0] * MM, a[1] * MM), (b[0] * MM, b[1] * MM), 0.1, False, number,
             centre_m=(centre[0] * MM, centre[1] * MM), sweep_rad=sweep if ccw else -sweep)  # fmt: skip
    return m


def path(points, first_line=1) -> list[Move]:
    return [line(a, b, first_line + i) for i, (a, b) in enumerate(zip(points[:-1], points[1:], strict=True))]


# -- the independent construction -----------------------------------------------------------------------------


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def left_normal(d):
    return np.array([-d[1], d[0]])


def offset_line(a, b, s, r):
    """The line a-b moved by r to the side s (+1 left, -1 right): two points (m)."""
    n = left_normal(unit(np.subtract(b, a)))
    return np.asarray(a) + s * r * n, np.asarray(b) + s * r * n


def intersect(p1, d1, p2, d2):
    """The point where p1 + t d1 meets p2 + u d2 (a 2x2 linear solve)."""
    t = np.linalg.solve(np.column_stack([d1, -np.asarray(d2)]), np.subtract(p2, p1))
    return np.asarray(p1) + t[0] * np.asarray(d1)


def line_circle(p, d, centre, radius, pick):
    """The intersections of p + t d (d a unit vector) with the circle, by the quadratic; ``pick`` chooses."""
    f = np.subtract(p, centre)
    b, c = float(f @ d), float(f @ f) - radius**2
    roots = [-b - math.sqrt(b * b - c), -b + math.sqrt(b * b - c)]
    return min((np.asarray(p) + t * np.asarray(d) for t in roots), key=pick)


def expected_polygon(points, s, r):
    """Tool-centre moves (kind, start, end, centre or None) of a polyline entered at points[0] and left
    at points[-1] (a line from outside to the part, around it, and back out), by the documented rules."""
    pts = [np.asarray(p, dtype=float) * MM for p in points]
    segs = list(zip(pts[:-1], pts[1:], strict=True))
    body = segs[:-1]  # the last is the exit
    offsets = [list(offset_line(a, b, s, r)) for a, b in body]
    offsets[0][0] = body[0][0]  # the entry starts at the uncompensated point
    # the entry's offset end is square to the entry itself (as the other ends)
    out: list[list] = []
    for i, (a, b) in enumerate(body):
        out.append(["line", offsets[i][0], offsets[i][1], None])
        if i + 1 == len(body):
            break
        d1, d2 = unit(b - a), unit(body[i + 1][1] - body[i + 1][0])
        cross = d1[0] * d2[1] - d1[1] * d2[0]
        if abs(cross) < 1e-12 and d1 @ d2 > 0:
            continue
        if cross * s > 0:  # turning towards the tool: concave, meet at the intersection
            q0 = offsets[i][1] if i else out[-1][2]
            point = intersect(q0, d1, offsets[i + 1][0], d2)
            out[-1][2] = point
            offsets[i + 1][0] = point
        else:  # convex: an arc of radius r around the corner
            out.append(["arc", offsets[i][1], offsets[i + 1][0], b])
    exit_start = out[-1][2]
    out.append(["line", exit_start, segs[-1][1], None])
    return out


def assert_path(got: list[Move], expected: list[list]) -> None:
    assert [m.kind for m in got] == [e[0] for e in expected]
    for m, (kind, start, end, centre) in zip(got, expected, strict=True):
        assert m.start_m == pytest.approx(tuple(start), abs=TOL)
        assert m.end_m == pytest.approx(tuple(end), abs=TOL)
        if kind == "arc":
            assert m.centre_m == pytest.approx(tuple(centre), abs=TOL)
            assert m.radius_m == pytest.approx(math.dist(start, centre), abs=TOL)
            assert m.arc_end_m == pytest.approx(tuple(end), abs=TOL)  # the sweep ends where the move ends
    for a, b in zip(got[:-1], got[1:], strict=True):
        assert a.end_m == pytest.approx(b.start_m, abs=TOL)  # continuous


def assert_arc(m: Move, start, end, centre, sweep) -> None:
    assert m.kind == "arc"
    assert m.start_m == pytest.approx(tuple(start), abs=TOL)
    assert m.end_m == pytest.approx(tuple(end), abs=TOL)
    assert m.centre_m == pytest.approx(tuple(centre), abs=TOL)
    assert m.sweep_rad == pytest.approx(sweep, abs=1e-9)


# -- a square: outside (convex corners, arcs) and inside (a pocket, intersections) ---------------------------------


def square_program(direction: str, outside: bool):
    """Enter at the middle of the bottom side square to it (from 10 mm outside, or from the centre), go round
    the 20 mm square, leave the way it came."""
    corners = [(20, 0), (20, 20), (0, 20), (0, 0)] if direction == "ccw" else [(0, 0), (0, 20), (20, 20), (20, 0)]
    middle = (10, 0)
    away = (10, -10) if outside else (10, 10)
    return [away, middle, *corners, middle, away]


@pytest.mark.parametrize(
    ("side", "direction", "outside"),
    [("left", "cw", True), ("right", "ccw", True), ("left", "ccw", False), ("right", "cw", False)],
)
def test_a_square_is_offset_by_the_tool_radius(side, direction, outside):
    points = square_program(direction, outside)
    s = 1 if side == "left" else -1
    got = compensate(path(points), side, R, "sq.ngc")
    expected = expected_polygon(points, s, R)
    assert_path(got, expected)
    corners = [e for e in expected if e[0] == "arc"]
    if outside:  # four arcs of radius 1.5 mm at the corners, the sides 1.5 mm outside the square
        assert len(corners) == 4
        sides = (-R, 20 * MM + R)
        for move in (m for m in got[1:-1] if m.kind == "line"):
            (x0, y0), (x1, y1) = move.start_m, move.end_m
            on_side = [abs(a - side) < TOL and abs(b - side) < TOL for a, b in ((x0, x1), (y0, y1)) for side in sides]
            assert any(on_side), move
        for move in (m for m in got if m.kind == "arc"):
            assert move.radius_m == pytest.approx(R, abs=TOL)
            assert abs(move.sweep_rad) == pytest.approx(math.pi / 2, abs=1e-12)
            assert (move.sweep_rad < 0) == (side == "left")  # around a convex corner, turning away from the tool
    else:  # a pocket: the corners are the offsets' intersections, 1.5 mm in from each wall
        assert corners == []
        inner = {(round(x / MM, 9), round(y / MM, 9)) for m in got[1:-1] for x, y in (m.start_m, m.end_m)}
        assert {(1.5, 1.5), (18.5, 1.5), (18.5, 18.5), (1.5, 18.5)} <= inner
    assert got[0].start_m == pytest.approx((0.010, 0.010 if not outside else -0.010))  # entered uncompensated
    assert got[-1].end_m == got[0].start_m  # and left uncompensated


def test_the_square_with_lines_numbered_as_the_program():
    points = square_program("cw", True)
    blocks = compensate_blocks(path(points, first_line=10), "left", R, "sq.ngc")
    assert len(blocks) == len(points) - 1
    # each convex corner's arc belongs to the block after it and comes first in it
    for number, block in enumerate(blocks, start=10):
        assert all(m.line == number for m in block)
    assert [m.kind for m in blocks[2]] == ["arc", "line"]


# -- arcs: outside they grow, inside they shrink ------------------------------------------------------------------


def d_shape():
    """A quarter disc of radius 10 mm entered up the y axis: the line out along x, the arc to (0, 10), the line
    back, the exit."""
    return [line((0, -10), (0, 0), 1), line((0, 0), (10, 0), 2), arc((10, 0), (0, 10), (0, 0), True, 3),
            line((0, 10), (0, 0), 4), line((0, 0), (-10, -10), 5)]  # fmt: skip


def test_an_arc_outside_grows_with_arcs_around_the_convex_corners():
    got = compensate(d_shape(), "right", R, "d.ngc")
    kinds = [m.kind for m in got]
    assert kinds == ["line", "line", "arc", "arc", "arc", "line", "line"]
    r_out = 10 * MM + R
    assert_arc(got[2], (10 * MM, -R), (10 * MM + R, 0), (10 * MM, 0), math.pi / 2)  # around (10, 0)
    assert_arc(got[3], (r_out, 0), (0, r_out), (0, 0), math.pi / 2)  # the arc, 1.5 mm larger
    assert_arc(got[4], (0, r_out), (-R, 10 * MM), (0, 10 * MM), math.pi / 2)  # around (0, 10)
    assert got[5].start_m == pytest.approx((-R, 10 * MM), abs=TOL)


def test_an_arc_inside_shrinks_and_meets_the_lines_at_their_intersections():
    got = compensate(d_shape(), "left", R, "d.ngc")
    # up y then along x turns away from the tool on the left: an arc; the other two corners are concave
    assert [m.kind for m in got] == ["line", "arc", "line", "arc", "line", "line"]
    assert_arc(got[1], (-R, 0), (0, R), (0, 0), -math.pi / 2)
    r_in = 10 * MM - R
    first = line_circle((0, R), np.array([1.0, 0.0]), (0, 0), r_in, pick=lambda p: -p[0])  # y = 1.5 on the circle
    second = line_circle((R, 0), np.array([0.0, 1.0]), (0, 0), r_in, pick=lambda p: -p[1])  # x = 1.5
    assert got[2].end_m == pytest.approx(tuple(first), abs=TOL)
    assert got[3].start_m == pytest.approx(tuple(first), abs=TOL)
    assert got[3].radius_m == pytest.approx(r_in, abs=TOL)
    assert got[3].end_m == pytest.approx(tuple(second), abs=TOL)
    assert got[3].arc_end_m == pytest.approx(tuple(second), abs=TOL)
    assert got[4].start_m == pytest.approx(tuple(second), abs=TOL)
    assert got[4].end_m == pytest.approx((R, 0), abs=TOL)


@pytest.mark.parametrize(("ccw", "side", "radius_mm"), [(False, "left", 11.5), (True, "left", 8.5)])
def test_a_full_circle_entered_square_to_it(ccw, side, radius_mm):
    """G2 with G41: the tool outside (11.5 mm); G3 with G41: inside, a round pocket (8.5 mm)."""
    outside = radius_mm > 10
    entry_from = (20, 0) if outside else (0, 0)
    moves = [line(entry_from, (10, 0), 1), arc((10, 0), (10, 0), (0, 0), ccw, 2), line((10, 0), entry_from, 3)]
    got = compensate(moves, side, R, "c.ngc")
    assert [m.kind for m in got] == ["line", "arc", "line"]
    d = np.array([-1.0, 0.0]) if outside else np.array([1.0, 0.0])
    p = np.asarray(entry_from, dtype=float) * MM + R * left_normal(d)  # the entry's offset line
    meet = line_circle(p, d, (0, 0), radius_mm * MM, pick=lambda q: abs(q[0] - 10 * MM))
    assert got[0].end_m == pytest.approx(tuple(meet), abs=TOL)  # a concave corner: where it meets the circle
    assert got[1].start_m == pytest.approx(got[0].end_m, abs=TOL)
    assert got[1].radius_m == pytest.approx(radius_mm * MM, abs=TOL)
    assert got[1].end_m == pytest.approx((radius_mm * MM, 0.0), abs=TOL)
    start_angle = math.atan2(got[1].start_m[1], got[1].start_m[0])
    assert abs(got[1].sweep_rad) == pytest.approx(2 * math.pi - abs(start_angle), abs=1e-12)
    assert got[2].start_m == pytest.approx((radius_mm * MM, 0.0), abs=TOL)
    assert got[2].end_m == pytest.approx((entry_from[0] * MM, 0.0), abs=TOL)


@pytest.mark.parametrize("m", [1, -1])
def test_two_arcs_meeting_at_a_concave_corner_meet_where_their_offsets_cross(m):
    """Two humps (G2 about (10, -10) and (30, -10)); G41 rides on top, where their junction is concave. And
    mirrored in y (m = -1): G3 about (10, 10) and (30, 10), G42 below."""
    moves = [
        line((-10, 0), (0, 0), 1),
        arc((0, 0), (20, 0), (10, -10 * m), m < 0, 2),
        arc((20, 0), (40, 0), (30, -10 * m), m < 0, 3),
        line((40, 0), (50, 0), 4),
        line((50, 0), (60, 0), 5),
    ]
    got = compensate(moves, "left" if m > 0 else "right", R, "m.ngc")
    big = math.sqrt(200) * MM + R
    meet = (20 * MM, m * (-10 * MM + math.sqrt(big**2 - (10 * MM) ** 2)))  # the circles' crossing, by symmetry
    arcs = [move for move in got if move.kind == "arc"]
    assert [move.kind for move in got] == ["line", "arc", "arc", "line", "line"]
    assert arcs[0].end_m == pytest.approx(meet, abs=TOL)
    assert arcs[1].start_m == pytest.approx(meet, abs=TOL)
    assert arcs[0].radius_m == pytest.approx(big, abs=TOL) and arcs[1].radius_m == pytest.approx(big, abs=TOL)
    # the lines before and after, 1.5 mm off y = 0, meet the grown circles (concave, the tool outside them)
    ahead = np.array([1.0, 0.0])
    first = line_circle((0, m * R), ahead, (10 * MM, -10 * MM * m), big, pick=lambda q: q[0])
    last = line_circle((0, m * R), ahead, (30 * MM, -10 * MM * m), big, pick=lambda q: -q[0])
    assert got[0].end_m == pytest.approx(tuple(first), abs=TOL) and arcs[0].start_m == got[0].end_m
    assert arcs[1].end_m == pytest.approx(tuple(last), abs=TOL) and got[3].start_m == arcs[1].end_m


def test_a_convex_corner_before_a_rapid_is_a_straight_rapid():
    moves = [line((0, -10), (0, 0), 1), line((0, 0), (10, 0), 2), line((10, 0), (10, -10), 3, rapid=True),
             line((10, -10), (20, -10), 4)]  # fmt: skip
    got = compensate(moves, "left", R, "r.ngc", ends_with_exit=False)
    # +y then +x turns right, away from the tool on the left: convex; so is +x then -y
    assert [m.kind for m in got] == ["line", "arc", "line", "line", "line", "line"]
    corner = got[3]
    assert corner.rapid and corner.line == 3
    assert corner.start_m == pytest.approx((10 * MM, R), abs=TOL)
    assert corner.end_m == pytest.approx((10 * MM + R, 0), abs=TOL)
    assert got[4].rapid and got[4].feed_m_s == math.inf


def test_an_entry_arc_keeps_its_start_and_ends_offset_on_its_radius():
    """convert_arc_comp1: the arc starts uncompensated, ends 1.5 mm out along the radius at its end, and its
    new centre sits on that radius, as far from both ends."""
    moves = [arc((10, 0), (0, 10), (0, 0), True, 1), line((0, 10), (-10, 10), 2)]
    got = compensate(moves, "right", R, "e.ngc", ends_with_exit=False)
    first = got[0]
    assert first.start_m == pytest.approx((10 * MM, 0), abs=TOL)
    assert first.end_m == pytest.approx((0, 10 * MM + R), abs=TOL)
    centre = np.asarray(first.centre_m)
    assert centre[0] == pytest.approx(0.0, abs=TOL)  # on the end's radius (the y axis)
    assert math.dist(centre, first.start_m) == pytest.approx(math.dist(centre, first.end_m), abs=TOL)
    assert first.arc_end_m == pytest.approx(first.end_m, abs=TOL)


# -- entry, exit, radius 0, a negative radius -------------------------------------------------------------------


def test_entry_and_exit_moves_follow_linuxcnc():
    """The entry ends offset square to itself, the exit starts where the tool is and ends uncompensated."""
    moves = [line((0, 0), (10, 0), 1), line((10, 0), (10, 10), 2), line((10, 10), (30, 30), 3)]
    got = compensate(moves, "right", R, "x.ngc")
    # +x then +y turns left, away from the tool on the right: convex, an arc around (10, 0)
    assert [m.kind for m in got] == ["line", "arc", "line", "line"]
    assert got[0].start_m == (0.0, 0.0)
    assert got[0].end_m == pytest.approx((10 * MM, -R), abs=TOL)
    assert got[2].end_m == pytest.approx((10 * MM + R, 10 * MM), abs=TOL)
    assert got[3].start_m == pytest.approx((10 * MM + R, 10 * MM), abs=TOL)
    assert got[3].end_m == (0.030, 0.030)
    open_end = compensate(moves, "right", R, "x.ngc", ends_with_exit=False)
    assert open_end[-1].end_m == pytest.approx((30 * MM + R / math.sqrt(2), 30 * MM - R / math.sqrt(2)), abs=TOL)


def test_a_zero_radius_returns_the_programmed_path():
    moves = path(square_program("cw", True))
    assert compensate(moves, "left", 0.0, "z.ngc") == moves


def test_a_negative_radius_cuts_on_the_other_side():
    moves = path(square_program("cw", True))
    assert compensate(moves, "left", -R, "n.ngc") == compensate(moves, "right", R, "n.ngc")
    short = [line((0, 0), (1, 0), 5), line((1, 0), (20, 0), 6)]
    assert error_of(short, radius=-R, ends_with_exit=False).startswith("bad.ngc:5: G41:")  # the code as programmed


# -- what the tool cannot do ------------------------------------------------------------------------------------


def error_of(moves, side="left", radius=R, **kwargs) -> str:
    with pytest.raises(GcodeError) as caught:
        compensate(moves, side, radius, "bad.ngc", **kwargs)
    text = str(caught.value)
    assert "\n" not in text
    return text


def test_a_slot_narrower_than_the_tool_is_a_concave_corner_error():
    """Along x, up 2 mm, back: the 3 mm tool's offsets of the 2 mm side would run backwards."""
    moves = path([(-10, 0), (0, 0), (10, 0), (10, 2), (0, 2), (-10, 2)])
    text = error_of(moves)
    assert text.startswith("bad.ngc:4: G41: concave corner the tool cannot reach without gouging")
    assert "the line of line 3 would run backwards" in text and "tool radius 1.5 mm" in text
    assert compensate(moves, "left", 0.9 * MM, "ok.ngc")  # a 1.8 mm tool fits


def test_an_inside_arc_smaller_than_the_tool_is_refused():
    moves = [line((0, -10), (2, 0), 1), arc((2, 0), (0, 2), (0, 0), True, 2), line((0, 2), (-10, 2), 3)]
    inside = [m for m in compensate(moves, "left", R, "ok.ngc") if m.line == 2 and m.kind == "arc"]
    assert inside[0].radius_m == pytest.approx(0.5 * MM, abs=TOL)  # G41 on a G3: inside; 1.5 mm fits in 2 mm
    text = error_of(moves, radius=2.0 * MM)
    assert text == ("bad.ngc:2: G41: tool radius larger than the arc: the tool does not fit inside the arc of "
                    "radius 2 mm (tool radius 2 mm)")  # fmt: skip
    text = error_of([arc((2, 0), (0, 2), (0, 0), True, 7), line((0, 2), (-10, 2), 8)], radius=2.5 * MM)
    assert text.startswith("bad.ngc:7: G41: tool radius larger than the arc")  # as the entry move too
    assert compensate(moves, "right", 2.0 * MM, "ok.ngc")  # outside it: 4 mm


def test_an_arc_then_a_line_the_tool_cannot_reach_is_refused():
    """Up x = 2 into a G3 of 2 mm (tangent), then straight down x = 0: the 1.5 mm tool's offsets miss."""
    moves = [line((2, -10), (2, 0), 1), arc((2, 0), (0, 2), (0, 0), True, 2), line((0, 2), (0, -10), 3),
             line((0, -10), (10, -10), 4)]  # fmt: skip
    assert error_of(moves).startswith("bad.ngc:3: G41: concave corner the tool cannot fit in without gouging: arc")
    assert compensate(moves, "left", 0.5 * MM, "ok.ngc")


def test_an_arc_turning_back_on_its_own_circle_is_refused():
    """G3 about the origin, then G2 back along the same circle: a U-turn of two arcs of one centre."""
    moves = [line((10, -10), (10, 0), 1), arc((10, 0), (0, 10), (0, 0), True, 2),
             arc((0, 10), (10, 0), (0, 0), False, 3), line((10, 0), (20, 0), 4)]  # fmt: skip
    assert error_of(moves).startswith("bad.ngc:3: G41: concave corner between two arcs of the same centre")


def test_the_entry_must_be_longer_than_the_tool_radius():
    text = error_of([line((0, 0), (1, 0), 5), line((1, 0), (20, 0), 6)], ends_with_exit=False)
    assert text == ("bad.ngc:5: G41: the entry move is 1 mm long, not longer than the tool radius "
                    "(tool radius 1.5 mm)")  # fmt: skip


def test_an_arc_just_after_g40_is_refused():
    moves = [line((0, 0), (10, 0), 1), line((10, 0), (20, 0), 2), arc((20, 0), (30, 0), (25, 0), True, 3)]
    assert error_of(moves, side="right").startswith("bad.ngc:3: G40: the move just after G40 must be a line")


def test_a_turn_within_the_tolerance_joins_as_it_is():
    """Under 0.05 rad LinuxCNC neither rounds nor intersects: the next offset starts where the last ended."""
    bend = 0.03
    far = (10 + 10 * math.cos(bend), 10 * math.sin(bend))
    for side in ("left", "right"):
        got = compensate([line((0, -10), (0, 0), 1), line((0, 0), (10, 0), 2), line((10, 0), far, 3),
                          line(far, (40, 0), 4)], side, R, "t.ngc")  # fmt: skip
        corner = ["arc"] if side == "left" else []  # at the entry: convex on the left, concave on the right
        assert [m.kind for m in got] == ["line", *corner, "line", "line", "line"]  # nothing at the 0.03 rad bend
        third = next(m for m in got if m.line == 3)
        second = [m for m in got if m.line == 2][-1]
        assert third.start_m == second.end_m == pytest.approx((10 * MM, R if side == "left" else -R), abs=TOL)
        s = 1 if side == "left" else -1
        normal = np.array([-math.sin(bend), math.cos(bend)])
        assert third.end_m == pytest.approx(tuple(np.array(far) * MM + s * R * normal), abs=TOL)


# -- any convex polygon: the tool centre stays at the radius from the part, outside and in ----------------------


def polygon_distance(polygon: list[Move], points: np.ndarray) -> np.ndarray:
    """Each point's exact distance to the closed polygon (the nearest of its sides), m."""
    table = MoveTable(polygon)
    n = len(points)
    return np.min([table.distance(np.full(n, k), points) for k in range(len(polygon))], axis=0)


def sampled(moves: list[Move]) -> np.ndarray:
    table = MoveTable(moves)
    out = []
    for k, move in enumerate(moves):
        u = np.linspace(0.0, move.length_m, 17)
        zero = np.zeros_like(u)
        out.append(table.kinematics(np.full(u.size, k), u, zero, zero, zero)[0])
    return np.concatenate(out)


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(3, 8),
    turn=st.floats(0.0, 2 * math.pi),
    jitter=st.lists(st.floats(-0.25, 0.25), min_size=8, max_size=8),
    radii=st.lists(st.floats(25.0, 35.0), min_size=8, max_size=8),
    outside=st.booleans(),
    ccw=st.booleans(),
)
def test_any_convex_polygon_is_cut_at_the_tool_radius(n, turn, jitter, radii, outside, ccw):
    angles = [turn + 2 * math.pi * (k + jitter[k]) / n for k in range(n)]
    corners = [(radii[k] * math.cos(a), radii[k] * math.sin(a)) for k, a in enumerate(angles)]
    hull = np.array(corners)
    sides = np.roll(hull, -1, axis=0) - hull
    cross = sides[:, 0] * np.roll(sides, -1, axis=0)[:, 1] - sides[:, 1] * np.roll(sides, -1, axis=0)[:, 0]
    dot = sides[:, 0] * np.roll(sides, -1, axis=0)[:, 0] + sides[:, 1] * np.roll(sides, -1, axis=0)[:, 1]
    assume(np.arctan2(cross, dot).min() > 0.06)  # convex, every corner turning by more than LinuxCNC's tolerance
    if not ccw:
        corners = corners[::-1]
    middle = tuple((np.add(corners[0], corners[1]) / 2).tolist())
    inward = tuple(hull.mean(axis=0).tolist())  # inside a convex polygon
    assume(math.dist(middle, inward) > 4.0)  # room for the entry move
    start = tuple((np.add(middle, np.subtract(middle, inward) * 0.5)).tolist()) if outside else inward
    points = [start, middle, *corners[1:], corners[0], middle, start]
    side = "left" if (ccw != outside) else "right"  # left of a ccw walk is inside
    got = compensate(path(points), side, R, "p.ngc")
    polygon = [line(a, b) for a, b in zip(corners, [*corners[1:], corners[0]], strict=True)]
    body = got[1:-1]  # without the entry and exit
    distance = polygon_distance(polygon, sampled(body))
    if outside:  # offset sides and corner arcs: everywhere exactly r from the part
        assert np.abs(distance - R).max() < 1e-9
        assert sum(m.kind == "arc" for m in body) == len(corners)
    else:  # a pocket: never nearer than r (no gouge), r along the sides, lines only
        assert distance.min() > R - 1e-9
        assert all(m.kind == "line" for m in got)
        ends = np.array([m.end_m for m in body[:-1]])
        assert np.abs(polygon_distance(polygon, ends) - R).max() < 1e-9
