"""An arc block's geometry from its words: centre by I J (relative to the start) or by R, LinuxCNC's tolerance.

An arc whose end is not on its circle is refused by LinuxCNC's rule
(interp_arc.cc): the radii to start and end differ by more than
``0.02 sqrt 2`` mm (0.002 sqrt 2 in) and by more than 0.1 % of the radius,
or by more than 100 times that. Within the rule the arc keeps its start
radius and ends on its circle at the angle of the programmed end; the next
block starts there.
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


def arc_move(
    words: dict[str, float],
    start: tuple[float, float],
    end: tuple[float, float],
    scale_m: float,
    ccw: bool,
    common: dict,
    error: Callable[[str, str], Exception],
) -> Move:
    """The arc from ``start`` to ``end`` (machine m); I J R in program units (``scale_m`` m each); P turns."""
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
        centre = (start[0] + words.get("I", 0.0) * s, start[1] + words.get("J", 0.0) * s)
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
    move = Move("arc", start, end, centre_m=centre, sweep_rad=sweep if ccw else -sweep, **common)
    on_circle = move.arc_end_m
    if math.hypot(on_circle[0] - end[0], on_circle[1] - end[1]) > 1e-12:
        end = (float(on_circle[0]), float(on_circle[1]))
    return Move("arc", start, end, centre_m=centre, sweep_rad=move.sweep_rad, **common)
