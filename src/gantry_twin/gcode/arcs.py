"""An arc block's geometry from its words: centre by I J or by R, LinuxCNC's tolerance for an end off the circle.

An arc whose end is not on its circle is refused by LinuxCNC's rule
(interp_arc.cc): the radii to start and end differ by more than
``0.02 sqrt 2`` mm (0.002 sqrt 2 in) and by more than 0.1 % of the radius,
or by more than 100 times that. Within the rule the arc ends at the
programmed end point, as LinuxCNC's: its path (LinuxCNC's canon: a spiral,
the radius changing in proportion to the angle turned) is followed here
by arcs of at most a quarter turn each, from one point of that spiral to
the next, each on the circle through its two ends whose centre is nearest
the programmed centre; every such arc but the last is a ``piece`` (its end
is not the block's).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from gantry_twin.gcode.geometry import Move

#: LinuxCNC's arc tolerances (rs274ngc_interp.hh): absolute, mm; relative.
ARC_RADIUS_TOLERANCE_MM = 0.02 * math.sqrt(2.0)
ARC_RADIUS_TOLERANCE_IN = 0.002 * math.sqrt(2.0)
ARC_RELATIVE_TOLERANCE = 0.001
MM_PER_INCH = 25.4
#: The most turns of an arc whose end is off its circle (followed in quarter turns: 4 moves a turn).
MAX_SPIRAL_TURNS = 1000


def arc_moves(
    words: dict[str, float],
    start: tuple[float, float],
    end: tuple[float, float],
    scale_m: float,
    ccw: bool,
    common: dict,
    error: Callable[[str, str], Exception],
    centre: tuple[float, float] | None = None,
) -> list[Move]:
    """The arc from ``start`` to ``end`` (machine m): ``centre`` (machine m, from I J) or R (program units,
    ``scale_m`` m each); P turns. One move, or several where the end is off the circle (the module's rule)."""
    s = scale_m
    word = "G3" if ccw else "G2"
    turns = words.get("P", 1.0)
    if turns < 1 or turns != int(turns):
        raise error("P", "arc turns must be a whole number >= 1")
    has_ij = "I" in words or "J" in words
    if has_ij and "R" in words:
        raise error("R", "an arc takes I J or R, not both")
    if not has_ij and "R" not in words:
        raise error(word, "an arc needs its centre (I J) or its radius (R)")
    chord = math.hypot(end[0] - start[0], end[1] - start[1])
    unit = "in" if s != 1e-3 else "mm"
    tolerance_abs_m = (ARC_RADIUS_TOLERANCE_IN * MM_PER_INCH if unit == "in" else ARC_RADIUS_TOLERANCE_MM) * 1e-3
    if has_ij:
        assert centre is not None
        r1 = math.hypot(start[0] - centre[0], start[1] - centre[1])
        r2 = math.hypot(end[0] - centre[0], end[1] - centre[1])
        if r1 <= 1e-9 or r2 <= 1e-9:
            raise error("I" if "I" in words else "J", "zero-radius arc (centre on an end point)")
        err = abs(r1 - r2)
        if err > 100.0 * tolerance_abs_m or (err > tolerance_abs_m and err / max(r1, r2) > ARC_RELATIVE_TOLERANCE):
            raise error(
                word,
                f"the end is not on the arc's circle: radius {r1 / s:.6g} {unit} at the start, "
                f"{r2 / s:.6g} {unit} at the end",
            )
    else:
        radius = words["R"] * s
        if chord <= 1e-12:
            raise error("R", "a full circle needs I J (R cannot place its centre)")
        if abs(radius) < 1e-12:
            raise error("R", "zero radius")
        half = 0.5 * chord
        if half > abs(radius) * (1.0 + 1e-9) + tolerance_abs_m * 1e-3:
            raise error("R", "radius too small to reach the end point")
        height = math.sqrt(max(radius * radius - half * half, 0.0))
        mid = (0.5 * (start[0] + end[0]), 0.5 * (start[1] + end[1]))
        # The centre to the right of start->end for G2 with R > 0 (arc <= 180 deg), left for G3.
        left = (-(end[1] - start[1]) / chord, (end[0] - start[0]) / chord)
        side = (1.0 if ccw else -1.0) * (1.0 if radius > 0 else -1.0)
        centre = (mid[0] + side * height * left[0], mid[1] + side * height * left[1])
    a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
    a1 = math.atan2(end[1] - centre[1], end[0] - centre[0])
    sweep = (a1 - a0) if ccw else (a0 - a1)
    sweep = math.fmod(sweep, 2.0 * math.pi)
    if sweep < 0.0:
        sweep += 2.0 * math.pi
    if sweep < 1e-12 or (chord <= tolerance_abs_m and has_ij and sweep > 2.0 * math.pi - 1e-6):
        sweep = 2.0 * math.pi  # the end is the start: a full circle
    sweep += 2.0 * math.pi * (turns - 1)
    off_circle = abs(math.dist(start, centre) - math.dist(end, centre)) > 1e-12
    if off_circle and turns > MAX_SPIRAL_TURNS:
        raise error("P", f"at most {MAX_SPIRAL_TURNS} turns for an arc whose end is off its circle (a spiral), "
                    f"got {turns:g}")  # fmt: skip
    return spiral_arcs(start, end, centre, sweep if ccw else -sweep, common)


def spiral_arcs(
    start: tuple[float, float], end: tuple[float, float], centre: tuple[float, float], sweep_rad: float, common: dict
) -> list[Move]:
    """The arc about ``centre`` turning ``sweep_rad`` (+ counter-clockwise) from ``start`` to ``end`` (m): one arc
    when both are on one circle, else arcs of at most a quarter turn through points of the spiral whose radius
    changes in proportion to the angle (LinuxCNC's path), each on the circle through its ends nearest ``centre``."""
    r1 = math.hypot(start[0] - centre[0], start[1] - centre[1])
    r2 = math.hypot(end[0] - centre[0], end[1] - centre[1])
    if abs(r2 - r1) <= 1e-12:
        return [Move("arc", start, end, centre_m=centre, sweep_rad=sweep_rad, **common)]
    count = max(1, math.ceil(abs(sweep_rad) / (0.5 * math.pi) - 1e-9))
    a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
    points = [start]
    for k in range(1, count):
        angle, radius = a0 + sweep_rad * k / count, r1 + (r2 - r1) * k / count
        points.append((centre[0] + radius * math.cos(angle), centre[1] + radius * math.sin(angle)))
    points.append(end)
    moves = []
    for k, (a, b) in enumerate(zip(points[:-1], points[1:], strict=True)):
        chord = (b[0] - a[0], b[1] - a[1])
        chord2 = chord[0] ** 2 + chord[1] ** 2
        ra2 = (a[0] - centre[0]) ** 2 + (a[1] - centre[1]) ** 2
        rb2 = (b[0] - centre[0]) ** 2 + (b[1] - centre[1]) ** 2
        t = (rb2 - ra2) / (2.0 * chord2) if chord2 > 0.0 else 0.0
        c = (centre[0] + t * chord[0], centre[1] + t * chord[1])  # on the bisector of a b, nearest the centre
        turn = math.atan2(b[1] - c[1], b[0] - c[0]) - math.atan2(a[1] - c[1], a[0] - c[0])
        turn = math.remainder(turn - sweep_rad / count, 2.0 * math.pi) + sweep_rad / count
        piece = k < count - 1
        moves.append(Move("arc", a, b, centre_m=c, sweep_rad=turn, **common, piece=piece))
    return moves
