"""A program as LinuxCNC's interpreter reads it: ``rs274 -g``'s canonical moves, in the twin's machine coordinates.

LinuxCNC's standalone interpreter ``rs274`` (run as a separate program)
prints the canonical calls a program makes, in the program's units of the
moment with 4 decimals, in work coordinates with the offsets apart. Here
they become the twin's :class:`~gantry_twin.gcode.geometry.Move` list (m,
machine coordinates: machine = rotate(work + G92, XY rotation) + G5x, as
LinuxCNC's canon applies them):

    STRAIGHT_TRAVERSE / STRAIGHT_FEED (x, y, z, ...)      a rapid / a line (Z alone: dropped)
    ARC_FEED (x_end, y_end, x_centre, y_centre, turns, z_end, ...)   an arc in the XY plane
    DWELL (s), SET_FEED_RATE (units/min), USE_LENGTH_UNITS, SET_G5X_OFFSET,
    SET_G92_OFFSET, SET_XY_ROTATION, SET_MOTION_CONTROL_MODE (exact stop / G64 P), MESSAGE, COMMENT

``NURBS_FEED`` (the splines G5, G5.1, G5.2) comes without its points: the
spline and the move after it (whose start is the spline's unknown end) are
one *unjudged* stretch from the last known point to the next known end point
(:attr:`CanonMove.judged` False). An arc in another plane moves Z with one
axis: unjudged too. Docs: docs/linuxcnc.md.
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from gantry_twin.cnc.session import LinuxCncError
from gantry_twin.gcode.geometry import Dwell, Move
from gantry_twin.gcode.program import GcodeError
from gantry_twin.settings import shorten

#: Seconds rs274 may take on one program.
RS274_TIMEOUT_S = 60.0
_CALL = re.compile(r"^\s*(\d+)\s+N\S*\s+([A-Z_0-9]+)\((.*)\)\s*$")


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


def read_canon(program: Path, tool_table: Path | None = None) -> CanonProgram:
    """Run ``rs274 -g`` on ``program`` and read its canonical moves; :class:`GcodeError` with rs274's own
    message and the line (found by its text) when LinuxCNC's interpreter refuses the program.

    rs274 runs in a directory of its own, which is also its HOME: it keeps its tool table's memory map
    (``.tool.mmap``) and parameter file there, and two rs274 sharing them fail at random."""
    command = ["rs274", "-g"]
    if tool_table is not None:
        command += ["-t", str(Path(tool_table).resolve())]
    command.append(str(Path(program).resolve()))
    with tempfile.TemporaryDirectory(prefix="gantry-twin-rs274-") as home:
        env = {**os.environ, "HOME": home, "TMPDIR": home}
        try:
            done = subprocess.run(
                command, capture_output=True, text=True, errors="replace", timeout=RS274_TIMEOUT_S, cwd=home,
                stdin=subprocess.DEVNULL, env=env,
            )  # fmt: skip
        except subprocess.TimeoutExpired:
            raise GcodeError(
                str(program), 0, "rs274", f"LinuxCNC's interpreter ran longer than {RS274_TIMEOUT_S:g} s"
            ) from None
    calls, error_lines = [], []
    for line in done.stdout.splitlines():
        match = _CALL.match(line)
        if match:
            calls.append((int(match.group(1)), match.group(2), match.group(3)))
        elif line.strip() and line.strip() != "executing":
            error_lines.append(line.strip())
    error_lines += [line.strip() for line in done.stderr.splitlines() if line.strip() and line.strip() != "executing"]
    if done.returncode < 0 or done.returncode > 128 or (done.returncode and not error_lines):
        signum = -done.returncode if done.returncode < 0 else done.returncode - 128
        how = f"signal {signum}" if done.returncode < 0 or done.returncode > 128 else f"status {done.returncode}"
        raise LinuxCncError(f"LinuxCNC's rs274 ended by {how} on {program} without a message")
    if done.returncode != 0:
        raise _refusal(program, error_lines)
    return _moves(program, calls)


def _refusal(program: Path, lines: list[str]) -> GcodeError:
    """rs274's message (its first line) at the line whose text it echoes (its second)."""
    what = lines[0] if lines else "LinuxCNC's interpreter refused the program"
    number = 0
    if len(lines) > 1:
        echoed = lines[1].strip()
        try:
            text = Path(program).read_text(encoding="ascii", errors="replace").splitlines()
        except OSError:
            text = []
        number = next((i for i, line in enumerate(text, start=1) if line.strip() == echoed), 0)
    return GcodeError(str(program), number, "LinuxCNC", shorten(what, 200))


def _numbers(args: str) -> list[float]:
    return [float(word) for word in args.split(",") if word.strip() and _is_number(word)]


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def _moves(program: Path, calls: list[tuple[int, str, str]]) -> CanonProgram:
    scale = 1e-3  # m per program unit
    g5x, g92, rotation = (0.0, 0.0), (0.0, 0.0), 0.0
    feed_m_s, exact_stop, tolerance_m = 0.0, True, math.inf
    plane_xy = True
    position = (0.0, 0.0)  # machine, m
    known = True  # the current position is known (not after a spline)
    items: list[Move | Dwell] = []
    unjudged: set[int] = set()
    messages: list[str] = []
    splines = 0
    pending_start: tuple[float, float] | None = None  # the last known point before an unjudged stretch

    def machine(x: float, y: float) -> tuple[float, float]:
        wx, wy = (x + g92[0]) * scale, (y + g92[1]) * scale
        c, s = math.cos(math.radians(rotation)), math.sin(math.radians(rotation))
        return (c * wx - s * wy + g5x[0] * scale, s * wx + c * wy + g5x[1] * scale)

    def add(end: tuple[float, float], rapid: bool, centre=None, sweep=0.0, judged=True) -> None:
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
        if not judged:
            unjudged.add(len(items) - 1)
        position = end

    number = 0  # the canonical call's number in rs274's listing: a move's ``line`` (rs274 prints no source line)
    for number, name, args in calls:
        v = _numbers(args)
        if name == "USE_LENGTH_UNITS":
            scale = 25.4e-3 if "INCHES" in args else 1e-3
        elif name == "SET_G5X_OFFSET" and len(v) >= 3:
            g5x = (v[1], v[2])
        elif name == "SET_G92_OFFSET" and len(v) >= 2:
            g92 = (v[0], v[1])
        elif name == "SET_XY_ROTATION" and v:
            rotation = v[0]
        elif name == "SELECT_PLANE":
            plane_xy = "XY" in args
        elif name == "SET_FEED_RATE" and v:
            feed_m_s = v[0] * scale / 60.0
        elif name == "SET_MOTION_CONTROL_MODE":
            exact_stop = "CONTINUOUS" not in args
            tolerance_m = v[0] * scale if (v and not exact_stop and v[0] > 0) else math.inf
        elif name in ("STRAIGHT_TRAVERSE", "STRAIGHT_FEED") and len(v) >= 2:
            add(machine(v[0], v[1]), name == "STRAIGHT_TRAVERSE")
        elif name == "ARC_FEED" and len(v) >= 5:
            if not plane_xy:  # Z and one axis: the XY path of such an arc is not printed as such
                pending_start = position if known else pending_start
                known = False
                continue
            end, centre = machine(v[0], v[1]), machine(v[2], v[3])
            turns = int(v[4])
            if not known:
                add(end, False)
                continue
            a0 = math.atan2(position[1] - centre[1], position[0] - centre[0])
            a1 = math.atan2(end[1] - centre[1], end[0] - centre[0])
            if turns > 0:
                sweep = (a1 - a0) % (2 * math.pi) or 2 * math.pi
                sweep += 2 * math.pi * (turns - 1)
            else:
                sweep = -((a0 - a1) % (2 * math.pi) or 2 * math.pi)
                sweep -= 2 * math.pi * (-turns - 1)
            add(end, False, centre, sweep)
        elif name == "NURBS_FEED":
            splines += 1
            if known:
                pending_start = position
            known = False
        elif name == "DWELL" and v:
            items.append(Dwell(v[0], number))
        elif name in ("MESSAGE", "COMMENT") and args.startswith('"'):
            text = args.strip('"')
            if name == "MESSAGE" or text.lower().startswith(("print,", "debug,", "msg,")):
                messages.append(text)
    return CanonProgram(str(program), tuple(items), tuple(messages), frozenset(unjudged), splines)
