"""A program as LinuxCNC's interpreter reads it: ``rs274 -g``'s canonical moves, in the twin's machine coordinates.

LinuxCNC's standalone interpreter ``rs274`` (run as a separate program, by
:func:`gantry_twin.gcode.oracle.run_rs274`) prints the canonical calls a
program makes, in the program's units of the moment with 4 decimals, in work
coordinates with the offsets apart;
:func:`gantry_twin.gcode.oracle.canonical_calls` reads them once, with the
units, offsets and rotation of each. Here they become the twin's
:class:`~gantry_twin.gcode.geometry.Move` list (m, machine coordinates:
machine = rotate(work + G92, XY rotation) + G5x, as LinuxCNC's canon
applies them):

    STRAIGHT_TRAVERSE / STRAIGHT_FEED (x, y, z, ...)      a rapid / a line (Z alone: dropped)
    ARC_FEED (x_end, y_end, x_centre, y_centre, turns, z_end, ...)   an arc in the XY plane
    DWELL (s), SET_FEED_RATE (units/min), USE_LENGTH_UNITS, SET_G5X_OFFSET,
    SET_G92_OFFSET, SET_XY_ROTATION, SET_MOTION_CONTROL_MODE (exact stop / G64 P), MESSAGE, COMMENT

``NURBS_FEED`` (the splines G5, G5.1, G5.2) comes without its points: the
spline and the move after it (whose start is the spline's unknown end) are
one *unjudged* stretch from the last known point to the next known end point
(:attr:`CanonProgram.unjudged`). An arc in another plane moves Z with one
axis: unjudged too. Docs: docs/linuxcnc.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from gantry_twin.cnc.session import LinuxCncError
from gantry_twin.gcode.geometry import Dwell, Move
from gantry_twin.gcode.oracle import Call, arc_sweep, canonical_calls, rs274_refusal, run_rs274
from gantry_twin.gcode.program import GcodeError
from gantry_twin.settings import shorten

#: Seconds rs274 may take on one program.
RS274_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class CanonProgram:
    """The canonical moves of a program (m, machine coordinates), its dwells, messages, and the stretches left
    unjudged (indices into ``items`` of moves whose geometry rs274 does not print)."""

    name: str
    items: tuple[Move | Dwell, ...]
    messages: tuple[str, ...]
    unjudged: frozenset[int]
    splines: int

    @property
    def moves(self) -> list[Move]:
        return [item for item in self.items if isinstance(item, Move)]


def read_canon(program: Path, tool_table: Path | None = None, subroutine_path: Sequence[Path] = ()) -> CanonProgram:
    """Run ``rs274 -b -g`` on ``program`` (:func:`gantry_twin.gcode.oracle.run_rs274`: block delete on, as
    the LinuxCNC session runs it, in a HOME of its own; subroutine files in ``subroutine_path``, then beside the
    program) and read its canonical moves; :class:`GcodeError`
    with rs274's own message and the line (found by its text) when LinuxCNC's interpreter refuses the program,
    :class:`LinuxCncError` when rs274 crashes or hangs."""
    code, output = run_rs274(program, tool_table, RS274_TIMEOUT_S, subroutine_path=subroutine_path)
    calls, message = canonical_calls(output)
    if code < 0 or code > 128 or (code and not message):
        how = f"signal {-code if code < 0 else code - 128}" if code != -1 else f"no end within {RS274_TIMEOUT_S:g} s"
        raise LinuxCncError(f"LinuxCNC's rs274 ended by {how} on {program} without a message")
    if code != 0:
        raise _refusal(program, output)
    return _moves(program, calls)


def _refusal(program: Path, output: str) -> GcodeError:
    """rs274's message (:func:`gantry_twin.gcode.oracle.rs274_refusal`) at the line whose text it echoes."""
    what, echoed = rs274_refusal(output)
    number = 0
    if echoed:
        try:
            text = Path(program).read_text(encoding="ascii", errors="replace").splitlines()
        except OSError:
            text = []
        number = next((i for i, line in enumerate(text, start=1) if line.strip() == echoed), 0)
    return GcodeError(
        str(program), number, "LinuxCNC", shorten(what or "LinuxCNC's interpreter refused the program", 200)
    )


def _moves(program: Path, calls: list[Call]) -> CanonProgram:
    feed_m_s, exact_stop, tolerance_m = 0.0, True, math.inf
    position = (0.0, 0.0)  # machine, m
    known = True  # the current position is known (not after a spline)
    items: list[Move | Dwell] = []
    unjudged: set[int] = set()
    messages: list[str] = []
    splines = 0
    pending_start: tuple[float, float] | None = None  # the last known point before an unjudged stretch

    def machine(c: Call, x: float, y: float) -> tuple[float, float]:
        mx, my = c.machine_mm(x, y)
        return (mx * 1e-3, my * 1e-3)

    def add(number: int, end, rapid: bool, centre=None, sweep=0.0) -> None:
        nonlocal position, known, pending_start
        if not known:
            # The spline's end is unknown: this move and the spline are one unjudged stretch to its end.
            start = pending_start if pending_start is not None else position
            items.append(Move("line", start, end, feed_m_s, False, number, exact_stop, tolerance_m))
            unjudged.add(len(items) - 1)
            position, known, pending_start = end, True, None
            return
        if math.dist(position, end) == 0.0 and centre is None:
            return  # Z alone, or no motion
        if centre is None:
            move = Move("line", position, end, math.inf if rapid else feed_m_s, rapid, number, exact_stop, tolerance_m)
        else:
            move = Move("arc", position, end, feed_m_s, False, number, exact_stop, tolerance_m, centre, sweep)
        items.append(move)
        position = end

    for c in calls:
        v = c.values
        if c.name == "SET_FEED_RATE" and v:
            feed_m_s = v[0] * c.scale * 1e-3 / 60.0
        elif c.name == "SET_MOTION_CONTROL_MODE":
            exact_stop = "CONTINUOUS" not in c.args
            tolerance_m = v[0] * c.scale * 1e-3 if (v and not exact_stop and v[0] > 0) else math.inf
        elif c.name in ("STRAIGHT_TRAVERSE", "STRAIGHT_FEED") and len(v) >= 2:
            add(c.number, machine(c, v[0], v[1]), c.name == "STRAIGHT_TRAVERSE")
        elif c.name == "ARC_FEED" and len(v) >= 5:
            if not c.plane_xy:  # Z and one axis: the XY path of such an arc is not printed as such
                pending_start = position if known else pending_start
                known = False
                continue
            end, centre = machine(c, v[0], v[1]), machine(c, v[2], v[3])
            if not known:
                add(c.number, end, False)
                continue
            add(c.number, end, False, centre, arc_sweep(position, end, centre, int(v[4])))
        elif c.name == "NURBS_FEED":
            splines += 1
            pending_start = position if known else pending_start
            known = False
        elif c.name == "DWELL" and v:
            items.append(Dwell(v[0], c.number))
        elif c.name in ("MESSAGE", "COMMENT") and c.args.startswith('"'):
            text = c.args.strip('"')
            if c.name == "MESSAGE" or text.lower().startswith(("print,", "debug,", "msg,")):
                messages.append(text)
    return CanonProgram(str(program), tuple(items), tuple(messages), frozenset(unjudged), splines)
