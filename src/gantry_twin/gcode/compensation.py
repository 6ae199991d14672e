"""Cutter radius compensation (G41 / G42, G40): the tool centre's path from the programmed outline.

LinuxCNC's rules (its G-code reference, G40 / G41 / G42, and its
interpreter: ``convert_straight_comp1/2``, ``convert_arc_comp1/2``,
``move_endpoint_and_flush`` in src/emc/rs274ngc), in the XY plane, for a
tool of radius r on the ``left`` (G41) or ``right`` (G42) of the path as
seen moving along it. Each move's end waits until the next move is known.

- **Entry** (the first move after G41 / G42, from the uncompensated
  position): a line goes to its end offset by r square to itself (it must
  be longer than r); an arc keeps its start and ends at its end offset by r
  along the radius, on a new centre found on that radius (the chord must be
  longer than r). The corner with the next move is then handled as any.
- **Lines and arcs** are offset by r to the side: a line is parallel, an
  arc concentric, r larger when the tool is outside it (G41 on a G2, G42
  on a G3), r smaller inside.
- **Corners**, by the turn between the end tangent of one move and the
  start tangent of the next (0.05 rad tolerance, LinuxCNC's
  TOLERANCE_CONCAVE_CORNER): a **convex** corner (the path turns away from
  the tool) gets an arc of radius r around the programmed corner, from one
  offset to the other; before a rapid (G0) that arc is a straight rapid. A
  **concave** corner (towards the tool) ends the previous move and starts
  the next at the intersection of their offsets (line-line, line-arc,
  arc-line, arc-arc). Within the tolerance the next move starts where the
  previous one ended (off its own offset by up to r times the turn; an arc
  starting there keeps that start's radius, so its end is off the next
  move's start by up to about r turn^2 / 2, nothing at a tangent junction).
  A U-turn after an arc that the tool is outside of is taken as concave
  (LinuxCNC's "h" and "m" shapes).
- **Exit** (the first move after G40): a line from where the tool is (the
  last move's offset end) to the programmed, uncompensated end.
- A radius of 0 changes nothing; a negative radius is its size on the
  other side (a tool table's D below the nominal diameter).

Errors (:class:`~gantry_twin.gcode.reader.GcodeError` on the line of the
move being placed; LinuxCNC's message in brackets):

- entry line not longer than r [Length of cutter compensation entry move is
  not greater than the tool radius]; entry arc's chord not longer than r
  [Radius of cutter compensation entry arc is not greater than the tool
  radius];
- **tool radius larger than the arc**: r >= the radius of an arc the tool
  is inside of, or an entry arc whose new centre does not exist [Tool
  radius not less than arc radius with comp];
- **concave corner**, the tool cannot reach it without gouging: the
  intersection moves a line's end back past its start [Straight feed (or
  traverse) in concave corner cannot be reached by the tool without
  gouging] or an arc's end back past its start (by more than 0.0254 rad)
  [Arc move in concave corner ...]; the offsets do not intersect, line to
  arc [Arc move in concave corner ...], arc to line [Arc to straight motion
  makes a corner the compensated tool can't fit in without gouging], arc to
  arc [Arc to arc motion makes a corner ...], or two arcs share their
  centre [Arc to arc motion is invalid because the arcs have the same
  center];
- an arc right after G40 [The move just after exiting cutter compensation
  mode must be straight, not an arc].

As in LinuxCNC: the reversal check on an entry line uses the direction
square to it (so an entry line is never refused by it); LinuxCNC's G40
section says the exit move must be longer than the tool diameter, its
interpreter does not check that, and neither does this. LinuxCNC's "BUG"
checks (radii that stop matching) cannot happen with these constructions and
are left out. Docs: docs/gcode.md.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from gantry_twin.gcode.geometry import Move
from gantry_twin.gcode.program import GcodeError

#: Corner angle tolerance, rad (LinuxCNC's TOLERANCE_CONCAVE_CORNER).
CORNER_TOLERANCE_RAD = 0.05
#: How far a concave corner may lengthen an arc before it counts as going back past its start, rad (LinuxCNC's
#: 0.0254 in a metric program).
ARC_SLACK_RAD = 0.0254
#: |cos| below which the entry arc's new centre does not exist (LinuxCNC's TOLERANCE_EQUAL).
_EQUAL = 1e-6
_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi
Point = tuple[float, float]


@dataclass(eq=False)
class _Out:
    """A tool-centre move being built; its end may still move (LinuxCNC's queued canon)."""

    source: Move
    start: Point
    end: Point
    centre: Point | None = None
    turn: int = 0  # arcs: full or partial circles, + counter-clockwise
    programmed_sweep: float = 0.0  # arcs: LinuxCNC's original_turns (0 for a corner arc: never checked)
    direction: Point = (0.0, 0.0)  # lines: the direction a pulled-back end must not reverse
    rapid: bool = False

    def move(self) -> Move:
        if self.centre is None:
            return dataclasses.replace(
                self.source, kind="line", start_m=self.start, end_m=self.end, centre_m=None, sweep_rad=0.0,
                rapid=self.rapid, feed_m_s=self.source.feed_m_s if not self.rapid else math.inf,
            )  # fmt: skip
        sweep = find_turn(self.start, self.centre, self.turn, self.end)
        return dataclasses.replace(
            self.source, kind="arc", start_m=self.start, end_m=self.end, centre_m=self.centre, sweep_rad=sweep,
            rapid=False,
        )  # fmt: skip


def compensate(
    moves: Sequence[Move],
    side: Literal["left", "right"],
    radius_m: float,
    file: str,
    *,
    ends_with_exit: bool = True,
) -> list[Move]:
    """The tool-centre moves of ``moves``: the entry move (first after G41 / G42) through the exit move.

    ``ends_with_exit``: the last move is the exit move (first after G40); False when the program ends with
    compensation on. Every output move keeps its block's feed, line and modes; a corner's arc is the next
    block's.
    """
    return [move for block in compensate_blocks(moves, side, radius_m, file, ends_with_exit=ends_with_exit)
            for move in block]  # fmt: skip


def compensate_blocks(
    moves: Sequence[Move],
    side: Literal["left", "right"],
    radius_m: float,
    file: str,
    *,
    ends_with_exit: bool = True,
) -> list[tuple[Move, ...]]:
    """As :func:`compensate`, per programmed move: its tool-centre moves (a corner's arc first), maybe none.

    For an interpreter that keeps dwells and other items between the moves: they go after their move's
    block.
    """
    if side not in ("left", "right"):
        raise ValueError(f"side is 'left' or 'right', got {side!r}")
    if not math.isfinite(radius_m):
        raise ValueError(f"radius_m must be finite, got {radius_m!r}")
    code = "G41" if side == "left" else "G42"  # as programmed, for the messages
    if radius_m < 0.0:
        side, radius_m = ("right" if side == "left" else "left"), -radius_m
    if radius_m == 0.0 or not moves:
        return [(move,) for move in moves]
    body = list(moves[:-1]) if ends_with_exit else list(moves)
    if not body:
        return [(moves[-1],)]
    comp = _Compensator(side, radius_m, file, code)
    comp.entry(body[0])
    for move in body[1:]:
        comp.next_move(move)
    if ends_with_exit:
        comp.exit(moves[-1])
    return [tuple(out.move() for out in block if not _empty(out)) for block in comp.blocks]


def _empty(out: _Out) -> bool:
    return out.centre is None and out.start == out.end


def find_turn(start: Point, centre: Point, turn: int, end: Point) -> float:
    """The signed angle an arc of ``turn`` circles sweeps from start to end around centre, rad (LinuxCNC's
    find_turn: an end at the start is a whole circle)."""
    if turn == 0:
        return 0.0
    alpha = math.atan2(start[1] - centre[1], start[0] - centre[0])
    beta = math.atan2(end[1] - centre[1], end[0] - centre[0])
    if turn > 0:
        if beta <= alpha:
            beta += _TWO_PI
        return (beta - alpha) + (turn - 1) * _TWO_PI
    if alpha <= beta:
        alpha += _TWO_PI
    return (beta - alpha) + (turn + 1) * _TWO_PI


def _turn_of(move: Move) -> int:
    """LinuxCNC's turn of a programmed arc: +-(whole or partial circles), + counter-clockwise."""
    circles = max(1, math.ceil(abs(move.sweep_rad) / _TWO_PI - 1e-9))
    return circles if move.sweep_rad > 0 else -circles


def _polar(origin: Point, length: float, angle: float) -> Point:
    return (origin[0] + length * math.cos(angle), origin[1] + length * math.sin(angle))


def _angle(frm: Point, to: Point) -> float:
    return math.atan2(to[1] - frm[1], to[0] - frm[0])


class _Compensator:
    """LinuxCNC's comp state: the programmed point, the tool's point and the one move whose end may move."""

    def __init__(self, side: str, radius_m: float, file: str, code: str) -> None:
        self.left = side == "left"
        self.code = code
        self.r = radius_m
        self.file = file
        self.blocks: list[list[_Out]] = []
        self.pending: _Out | None = None
        self.programmed: Point = (0.0, 0.0)
        self.current: Point = (0.0, 0.0)

    def error(self, move: Move, what: str) -> GcodeError:
        return GcodeError(self.file, move.line, self.code, f"{what} (tool radius {self.r * 1e3:.6g} mm)")

    def inside(self, turn: int) -> bool:
        """The tool is inside an arc turning this way (LinuxCNC's TOOL_INSIDE_ARC)."""
        return (self.left and turn > 0) or (not self.left and turn < 0)

    def queue(self, out: _Out) -> None:
        self.blocks[-1].append(out)
        self.pending = out

    def flush(self, out: _Out) -> None:
        self.blocks[-1].append(out)

    def entry(self, move: Move) -> None:
        self.blocks.append([])
        start, end = move.start_m, move.end_m
        if move.centre_m is None:  # convert_straight_comp1
            if math.dist(start, end) <= self.r:
                raise self.error(
                    move, f"the entry move is {math.dist(start, end) * 1e3:.6g} mm long, not longer than the tool "
                    "radius",
                )  # fmt: skip
            alpha = _angle(start, end) + (_HALF_PI if self.left else -_HALF_PI)
            tool_end = _polar(end, self.r, alpha)
            self.queue(_Out(move, start, tool_end, direction=(math.cos(alpha), math.sin(alpha)), rapid=move.rapid))
            self.current, self.programmed = tool_end, end
            return
        self._entry_arc(move)

    def _entry_arc(self, move: Move) -> None:  # convert_arc_comp1
        start, end, centre = move.start_m, move.end_m, move.centre_m
        assert centre is not None
        turn = _turn_of(move)
        if math.dist(start, end) <= self.r:
            raise self.error(
                move, f"the entry arc's ends are {math.dist(start, end) * 1e3:.6g} mm apart, not more than the tool "
                "radius",
            )  # fmt: skip
        if self.inside(turn) and move.radius_m <= self.r:
            raise self._larger_than_arc(move, move.radius_m)
        gamma = _angle(end, centre) if self.inside(turn) else _angle(centre, end)
        tool_end = _polar(end, self.r, gamma)
        half_chord = 0.5 * math.dist(start, tool_end)
        towards_centre = _angle(tool_end, centre)
        a = _angle(tool_end, start) - towards_centre
        if abs(math.cos(a)) < _EQUAL:
            raise self._larger_than_arc(move, move.radius_m)
        new_centre = _polar(tool_end, half_chord / math.cos(a), towards_centre)
        out = _Out(move, start, tool_end, new_centre, turn)
        out.programmed_sweep = find_turn(start, new_centre, turn, tool_end)
        self.queue(out)
        self.current, self.programmed = tool_end, end

    def _larger_than_arc(self, move: Move, arc_radius_m: float) -> GcodeError:
        return self.error(
            move, f"tool radius larger than the arc: the tool does not fit inside the arc of radius "
            f"{arc_radius_m * 1e3:.6g} mm",
        )  # fmt: skip

    def next_move(self, move: Move) -> None:
        self.blocks.append([])
        if move.centre_m is None:
            self._line(move)
        else:
            self._arc(move)

    def _line(self, move: Move) -> None:  # convert_straight_comp2
        op, c, p = self.programmed, self.current, move.end_m
        if p == op:
            return  # no XY motion
        prev = self.pending
        assert prev is not None
        theta, alpha = _angle(op, c), _angle(op, p)
        if self.left:
            if theta < alpha:
                theta += _TWO_PI
            beta, gamma = theta - alpha - _HALF_PI, _HALF_PI
        else:
            if alpha < theta:
                alpha += _TWO_PI
            beta, gamma = alpha - theta - _HALF_PI, -_HALF_PI
        small = CORNER_TOLERANCE_RAD
        end = _polar(p, self.r, alpha + gamma)
        mid = _polar(op, self.r, alpha + gamma)
        h_shape = (
            beta > math.pi - small and prev.centre is not None
            and ((not self.left and prev.turn > 0) or (self.left and prev.turn < 0))
        )  # fmt: skip
        concave = beta < -small or beta > math.pi + small or h_shape
        start = c
        if not concave and beta > small:  # convex: around the corner
            self._move_end(move, c)
            if move.rapid:
                self.flush(_Out(move, c, mid, rapid=True))
            else:
                self.flush(_Out(move, c, mid, op, -1 if self.left else 1))
            start = mid
        elif concave and prev.centre is None:  # line -> line: the offsets' intersection
            retreat = self.r / math.tan(0.5 * (beta + math.pi))
            start = _polar(c, retreat, theta + gamma)
            self._move_end(move, start)
        elif concave:
            start = self._arc_to_line(move, prev, op, p)
            self._move_end(move, start)
        self.queue(_Out(move, start, end, direction=(p[0] - op[0], p[1] - op[1]), rapid=move.rapid))
        self.current, self.programmed = end, p

    def _arc_to_line(self, move: Move, prev: _Out, op: Point, p: Point) -> Point:
        assert prev.centre is not None
        old_radius = math.dist(prev.centre, prev.end)
        base = _angle(op, p)
        theta = base + _HALF_PI if prev.turn > 0 else base - _HALF_PI
        phi = _angle(op, prev.centre)
        inside = self.inside(prev.turn)
        programmed_radius = old_radius + self.r if inside else old_radius - self.r
        d = programmed_radius * math.cos(theta - phi)  # the old centre's distance from the new line
        ratio = (d - self.r if inside else d + self.r) / old_radius
        if abs(ratio) > 1.0:
            raise self.error(move, "concave corner the tool cannot fit in without gouging: arc to line")
        turn_back = -math.acos(ratio) if (prev.turn > 0) == inside else math.acos(ratio)
        return _polar(prev.centre, old_radius, turn_back + theta + math.pi)

    def _arc(self, move: Move) -> None:  # convert_arc_comp2
        op, c, end = self.programmed, self.current, move.end_m
        centre = move.centre_m
        assert centre is not None
        prev = self.pending
        assert prev is not None
        turn = _turn_of(move)
        arc_radius = math.dist(centre, end)
        theta = _angle(op, c) + (-_HALF_PI if self.left else _HALF_PI)
        delta = _angle(op, centre)
        alpha = delta - _HALF_PI if turn > 0 else delta + _HALF_PI
        beta = theta - alpha if self.left else alpha - theta
        if beta > 1.5 * math.pi:
            beta -= _TWO_PI
        elif beta < -_HALF_PI:
            beta += _TWO_PI
        inside = self.inside(turn)
        if inside:
            gamma = _angle(end, centre)
            if arc_radius <= self.r:
                raise self._larger_than_arc(move, arc_radius)
        else:
            gamma = _angle(centre, end)
            delta += math.pi
        tool_end = _polar(end, self.r, gamma)
        small = CORNER_TOLERANCE_RAD
        out = _Out(move, c, tool_end, centre, turn, programmed_sweep=find_turn(op, centre, turn, end))
        if beta < -small or beta > math.pi + small or (abs(beta - math.pi) < small and not inside):  # concave
            if prev.centre is None:
                out.start = self._line_to_arc(move, arc_radius, beta, theta, inside, turn, centre)
            else:
                out.start = self._arc_to_arc(move, prev, arc_radius, inside, turn, centre)
            self._move_end(move, out.start)
        elif beta > small:  # convex: around the corner, then the arc
            out.start = _polar(op, self.r, delta)
            self.flush(_Out(move, c, out.start, op, -1 if self.left else 1))
        self.queue(out)
        self.current, self.programmed = tool_end, end

    def _line_to_arc(
        self, move: Move, arc_radius: float, beta: float, theta: float, inside: bool, turn: int, centre: Point
    ) -> Point:
        across = arc_radius * math.sin(beta - _HALF_PI)
        if inside:
            distance = arc_radius - self.r
            ratio = (across + self.r) / distance
        else:
            distance = arc_radius + self.r
            ratio = (across - self.r) / distance
        if abs(ratio) > 1.0:
            raise self.error(move, "concave corner the tool cannot reach without gouging: line to arc")
        if inside:
            angle = theta + math.asin(ratio) if turn > 0 else theta - math.asin(ratio)
        else:
            angle = theta + math.pi - math.asin(ratio) if turn > 0 else theta + math.pi + math.asin(ratio)
        return _polar(centre, distance, angle)

    def _arc_to_arc(self, move: Move, prev: _Out, arc_radius: float, inside: bool, turn: int, centre: Point) -> Point:
        assert prev.centre is not None
        old_radius = math.dist(prev.centre, prev.end)
        new_radius = arc_radius - self.r if inside else arc_radius + self.r
        apart = math.dist(prev.centre, centre)
        if old_radius == 0.0 or apart == 0.0:
            raise self.error(move, "concave corner between two arcs of the same centre")
        cos_pullback = (old_radius**2 + apart**2 - new_radius**2) / (2.0 * old_radius * apart)
        if abs(cos_pullback) > 1.0:
            raise self.error(move, "concave corner the tool cannot fit in without gouging: arc to arc")
        pullback = math.acos(cos_pullback)
        towards = _angle(prev.centre, centre)
        sign = 1.0 if (turn > 0) == self.inside(prev.turn) else -1.0
        return _polar(prev.centre, old_radius, towards + sign * pullback)

    def _move_end(self, move: Move, point: Point) -> None:
        """Move the pending move's end to ``point`` (LinuxCNC's move_endpoint_and_flush), if it stays forward."""
        prev = self.pending
        assert prev is not None
        if prev.centre is None:
            forward = prev.direction[0] * (point[0] - prev.start[0]) + prev.direction[1] * (point[1] - prev.start[1])
            if forward < 0.0:
                what = "rapid" if prev.rapid else "line"
                raise self.error(
                    move, f"concave corner the tool cannot reach without gouging: the {what} of line "
                    f"{prev.source.line} would run backwards",
                )  # fmt: skip
        elif prev.programmed_sweep != 0.0:
            sweep = find_turn(prev.start, prev.centre, prev.turn, point)
            if abs(sweep) > abs(prev.programmed_sweep) + ARC_SLACK_RAD:
                raise self.error(
                    move, f"concave corner the tool cannot reach without gouging: the arc of line "
                    f"{prev.source.line} would run backwards",
                )  # fmt: skip
        prev.end = point
        self.pending = None

    def exit(self, move: Move) -> None:  # convert_cutter_compensation_off, then the next straight move
        self.blocks.append([])
        if move.centre_m is not None:
            raise GcodeError(
                self.file, move.line, "G40",
                "the move just after G40 must be a line (G0 or G1), not an arc (it leaves the compensated path)",
            )  # fmt: skip
        if self.pending is not None:
            self._move_end(move, self.pending.end)
        self.flush(_Out(move, self.current, move.end_m, rapid=move.rapid))
