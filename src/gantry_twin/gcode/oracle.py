"""LinuxCNC's standalone interpreter ``rs274`` as an oracle for the reader: the same program, the same XY path?

``rs274 -b -g FILE`` (Debian's ``linuxcnc-uspace``; ``-b`` skips the lines
starting ``/``, as the reader does by default) prints the canonical calls
LinuxCNC's interpreter makes, in the program's units with 4 decimals, the
moves in work coordinates and the offsets apart (``SET_G5X_OFFSET``,
``SET_G92_OFFSET``, ``SET_XY_ROTATION``). :func:`rs274_path` reads that
into machine coordinates, mm, as LinuxCNC's canon composes them::

    machine = rotate(work + G92 offset, XY rotation) + G5x offset

and :func:`compare` walks it beside the reader's moves (:func:`twin_path`):
the end of every rapid, line and arc, and an arc's turns (direction and
count) and centre (within what the end off its circle allows: the
reader's arc runs through both ends, on the circle nearest the programmed
centre; past a quarter turn it follows LinuxCNC's spiral in pieces and
the centre is not compared), motion that leaves X Y where they are (Z only)
dropped (an arc back to its start is a full circle), within 1 um (3 um where the program is in inches: rs274 prints
0.1 mil). A spline prints as ``NURBS_FEED`` without its points: its end
counts as whatever the reader's spline ends at, and the moves after it
check it. Docs: docs/gcode.md ("LinuxCNC's interpreter as the oracle").
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from gantry_twin.gcode.geometry import Move, bounding_box
from gantry_twin.gcode.program import Program

#: Agreement: mm programs, inch programs (rs274 prints 4 decimals: 2.54 um in inches), mm.
TOLERANCE_MM = {"mm": 1e-3, "in": 3e-3}
#: Two points rs274 printed are one (4 decimals, offsets and rotation printed rounded apart), mm.
SAME_POINT_MM = {"mm": 0.2e-3, "in": 3e-3}
#: A move of the reader's this short may have no point of rs274's: rs274 rounds both its ends to 0.1 um and
#: may print it as no motion (a move of 0.34 um as one of 0.2 um), mm; 0.1 mil rounding in inches.
READER_SAME_MM = {"mm": 0.35e-3, "in": 3e-3}
#: The most alignments :func:`compare` goes on with at once (a run of short moves on both sides branches it).
ALIGNMENTS_MAX = 64
UNITS_MM = {"CANON_UNITS_MM": 1.0, "CANON_UNITS_INCHES": 25.4, "CANON_UNITS_CM": 10.0}
_CALL = re.compile(r"^\s*(\d+)\s+N\S*\s+([A-Z_0-9]+)\((.*)\)\s*$")
_PLAIN_PATH = re.compile(r"[A-Za-z0-9_./+-]+")
_LISTED = re.compile(r"^\s*\d+\s+N\S*\s+[A-Z_0-9]+\(")  # a call's line, even one cut short
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
#: Canonical calls that move and cannot be an XY gantry's (probing, spindle-synchronised and lathe motion).
FOREIGN = {"STRAIGHT_PROBE": "probing", "RIGID_TAP": "spindle-synchronised motion (rigid tapping)"}


@dataclass(frozen=True)
class Point:
    """One end point, machine mm: kind "rapid", "line", "arc" or "spline" (x, y None: rs274 does not print it);
    ``unit`` the program's units when rs274 printed it ("mm" or "in"); ``line`` the rs274 output line (the
    reader's: the program line); an arc's centre, turns and the slack its end off the circle gives."""

    kind: str
    x: float | None
    y: float | None
    unit: str = "mm"
    line: int = 0
    centre: tuple[float, float] | None = None  # an arc's (machine mm)
    turns: int = 0  # an arc's: + counter-clockwise, the number of turns started (P)
    slack: float = 0.0  # mm: how far the centre of the circle through both ends is from ``centre``


@dataclass(frozen=True)
class Rs274Path:
    """What rs274 made of a program: ok (it ran to its end), its message when not, the points, whether
    every arc was in the XY plane, the moves' bounding box (mm: xmin, ymin, xmax, ymax), any foreign motion."""

    ok: bool
    message: str
    points: tuple[Point, ...]
    xy_plane: bool
    extent_mm: tuple[float, float, float, float]
    foreign: str = ""


def rs274_available() -> str | None:
    """The path of ``rs274``, or None where LinuxCNC is not installed."""
    return shutil.which("rs274")


def run_rs274(
    program: str | Path,
    tool_table: str | Path | None = None,
    timeout_s: float = 60.0,
    block_delete: bool = True,
    subroutine_path: Sequence[str | Path] = (),
) -> tuple[int, str]:
    """Run ``rs274 -g`` on ``program`` (with ``-t`` the tool table; ``-b``, block delete on, as the reader's
    default, unless ``block_delete`` is False): its exit status and output (-1 and why, past ``timeout_s``).

    Every LinuxCNC program that reads a program (``rs274`` here, :mod:`gantry_twin.cnc`) runs through this.
    rs274 runs in a directory of its own that is also its HOME: it maps ``$HOME/.tool.mmap`` and writes its
    parameter file there, and a dozen rs274 sharing one map crashed some with SIGBUS. A subroutine called
    by name (``o<NAME> call``) is found as the reader finds it (:func:`subroutine_dirs`; an INI of two lines
    gives rs274 its ``[RS274NGC] SUBROUTINE_PATH``, :func:`link_subroutine_path`)."""
    exe = rs274_available()
    if exe is None:
        raise FileNotFoundError("rs274 is not installed (Debian: apt install linuxcnc-uspace)")
    program = Path(program).resolve()
    table = ["-t", str(Path(tool_table).resolve())] if tool_table is not None else []
    with tempfile.TemporaryDirectory(prefix="gantry-twin-rs274-") as home:
        searched = link_subroutine_path(Path(home), subroutine_dirs(program, subroutine_path))
        ini = Path(home) / "rs274.ini"
        ini.write_text(f"[RS274NGC]\nSUBROUTINE_PATH = {searched}\n")
        command = [exe, "-i", str(ini), *table, *(["-b"] if block_delete else []), "-g", str(program)]
        env = {**os.environ, "HOME": home, "TMPDIR": home}
        try:
            done = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s, errors="replace",
                                  stdin=subprocess.DEVNULL, check=False, cwd=home, env=env)  # fmt: skip
        except subprocess.TimeoutExpired:
            return -1, f"rs274 did not finish within {timeout_s:g} s"
    return done.returncode, done.stdout + done.stderr


def subroutine_dirs(program: str | Path, subroutine_path: Sequence[str | Path] = ()) -> list[Path]:
    """Where a subroutine file ``NAME.ngc`` that ``program`` calls is looked for, in order: the directories of
    ``subroutine_path``, then the program's own (the reader's order, :mod:`gantry_twin.gcode.interpreter`)."""
    return [Path(d).resolve() for d in subroutine_path] + [Path(program).resolve().parent]


def link_subroutine_path(directory: Path, dirs: Sequence[Path]) -> str:
    """LinuxCNC's ``[RS274NGC] SUBROUTINE_PATH`` for ``dirs``: the ``*.ngc`` files of each linked into a directory
    of its own in ``directory`` (``subroutines-0``, ...), and those listed. LinuxCNC resolves each listed
    directory (a linked directory would be its target again), splits the value at ``:`` and expands each part
    with ``wordexp`` when it looks for a file (a space splits it, ``$(...)`` runs), so no name of the user's
    directories may reach it. "" (no file found) where ``directory``'s own path is not plain (letters, digits,
    ``_ . / + -``)."""
    base = directory.resolve()
    if _PLAIN_PATH.fullmatch(str(base)) is None:
        return ""
    listed = []
    for k, target in enumerate(dirs):
        here = base / f"subroutines-{k}"
        here.mkdir()
        for file in sorted(Path(target).glob("*.ngc")):
            (here / file.name).symlink_to(file.resolve())
        listed.append(str(here))
    return ":".join(listed)


@dataclass(frozen=True)
class Call:
    """One canonical call rs274 printed: its number in the listing, name, argument text and numbers, and the
    state it was made in: the program's unit ("mm", "in"; ``scale`` mm per unit), the offsets (mm), the XY
    rotation (degrees) and whether the plane is XY."""

    number: int
    name: str
    args: str
    values: tuple[float, ...]
    unit: str
    scale: float
    g5x_mm: tuple[float, float]
    g92_mm: tuple[float, float]
    rotation_deg: float
    plane_xy: bool

    def machine_mm(self, x: float, y: float) -> tuple[float, float]:
        """Work coordinates (program units) -> machine mm: rotate(work + G92, rotation) + G5x (LinuxCNC's canon)."""
        return _machine(x, y, self.scale, self.g92_mm, self.rotation_deg, self.g5x_mm)


def canonical_calls(output: str) -> tuple[list[Call], str]:
    """rs274's output read once: every canonical call with the state it was made in (units, offsets, rotation
    and plane follow USE_LENGTH_UNITS, SET_G5X_OFFSET, SET_G92_OFFSET, SET_XY_ROTATION and SELECT_PLANE as they
    come), and rs274's message when it stopped (:func:`rs274_refusal`: the message, then the line it echoes)."""
    scale, unit = 1.0, "mm"
    g5x, g92, rotation, plane_xy = (0.0, 0.0), (0.0, 0.0), 0.0, True
    calls = []
    what, echoed = rs274_refusal(output)
    message = f"{what} (at: {echoed})" if echoed else what
    for raw in output.splitlines():
        match = _CALL.match(raw)
        if match is None:
            continue
        number, call, args = int(match.group(1)), match.group(2), match.group(3)
        values = tuple(_numbers(args))
        if call == "USE_LENGTH_UNITS":
            scale = UNITS_MM.get(args.strip(), 1.0)
            unit = "in" if scale == 25.4 else "mm"
        elif call == "SET_G5X_OFFSET":
            g5x = (values[1] * scale, values[2] * scale)
        elif call == "SET_G92_OFFSET":
            g92 = (values[0] * scale, values[1] * scale)
        elif call == "SET_XY_ROTATION":
            rotation = values[0]
        elif call == "SELECT_PLANE":
            plane_xy = "XY" in args
        calls.append(Call(number, call, args, values, unit, scale, g5x, g92, rotation, plane_xy))
    return calls, message


def rs274_refusal(output: str) -> tuple[str, str]:
    """rs274's message when it stopped and the program line it echoes after it, as written ("" each where there is
    none): the lines of its standard error, which :func:`run_rs274` puts last and rs274 starts with
    "executing" (a ``(print, ...)`` goes to its standard output, before)."""
    lines = output.splitlines()
    starts = [k for k, line in enumerate(lines) if line.strip() == "executing"]
    errors = [line.strip() for line in lines[starts[-1] + 1 if starts else 0 :] if line.strip()]
    errors = [line for line in errors if not _LISTED.match(line)]
    return (errors[0] if errors else "", errors[1] if len(errors) > 1 else "")


def _numbers(text: str) -> list[float]:
    return [float(v) for v in _NUMBER.findall(text)]


def rs274_path(returncode: int, output: str) -> Rs274Path:
    """Read rs274's canonical calls into machine points (mm), as this module's docstring says."""
    xy_plane, foreign = True, ""
    points: list[Point] = []
    moves: list[Move] = []
    position = (0.0, 0.0)
    calls, message = canonical_calls(output)
    for c in calls:
        if c.name in FOREIGN:
            foreign = foreign or FOREIGN[c.name]
        elif c.name == "NURBS_FEED":
            points.append(Point("spline", None, None, c.unit, c.number))
        elif c.name in ("STRAIGHT_TRAVERSE", "STRAIGHT_FEED", "ARC_FEED"):
            values = c.values
            if c.name == "ARC_FEED" and not c.plane_xy:
                xy_plane = False
                continue
            end = c.machine_mm(values[0], values[1])
            kind = {"STRAIGHT_TRAVERSE": "rapid", "STRAIGHT_FEED": "line", "ARC_FEED": "arc"}[c.name]
            if kind != "arc":
                points.append(Point(kind, end[0], end[1], c.unit, c.number))
                moves.append(Move("line", position, end, 1.0, False, 0))
            else:
                centre = c.machine_mm(values[2], values[3])
                turn = int(values[4])
                chord = math.dist(position, end)
                r1, r2 = math.dist(centre, position), math.dist(centre, end)
                slack = abs(r2 * r2 - r1 * r1) / (2.0 * chord) if chord > 1e-9 else math.inf
                points.append(Point(kind, end[0], end[1], c.unit, c.number, centre, turn, slack))
                moves.append(Move("arc", position, end, 1.0, False, 0, centre_m=centre,
                                  sweep_rad=arc_sweep(position, end, centre, turn)))  # fmt: skip
            position = end
    if moves:
        lo, hi = bounding_box(moves)
        extent = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    else:
        extent = (0.0, 0.0, 0.0, 0.0)
    ok = returncode == 0
    return Rs274Path(ok, "" if ok else message, tuple(points), xy_plane, extent, foreign)


def arc_sweep(start: tuple[float, float], end: tuple[float, float], centre: tuple[float, float], turn: int) -> float:
    """The signed sweep (rad, + counter-clockwise) of ARC_FEED's arc from ``start`` to ``end`` about ``centre``
    with rs274's turn count ``turn`` (+ counter-clockwise; |turn| - 1 extra full turns)."""
    a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
    a1 = math.atan2(end[1] - centre[1], end[0] - centre[0])
    sweep = math.fmod((a1 - a0) * (1 if turn > 0 else -1), 2.0 * math.pi) % (2.0 * math.pi)
    sweep = (sweep or 2.0 * math.pi) + 2.0 * math.pi * (abs(turn) - 1)
    return math.copysign(sweep, turn)


def _machine(
    x: float, y: float, scale: float, g92: tuple[float, float], degrees: float, g5x: tuple[float, float]
) -> tuple[float, float]:
    """Work coordinates (program units) -> machine mm: rotate(work + G92, rotation) + G5x (LinuxCNC's canon)."""
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    wx, wy = x * scale + g92[0], y * scale + g92[1]
    return c * wx - s * wy + g5x[0], s * wx + c * wy + g5x[1]


def twin_path(program: Program) -> tuple[Point, ...]:
    """The reader's path as points, machine mm: its start, then the end of every block's moves (the pieces of
    a block split into several moves, a spline's arcs or an off-circle arc's, left out)."""
    points = [Point("start", program.start_m[0] * 1e3, program.start_m[1] * 1e3)]
    whole, sweep = True, 0.0  # the move is a whole block (not the last piece of one); the block's turn so far
    for move in program.moves:
        if move.kind == "line" and math.dist(move.start_m, move.end_m) < 1e-9:
            continue  # shorter than 1 nm: rs274 prints no motion (4 decimals)
        sweep += move.sweep_rad
        if not move.piece:
            kind = "rapid" if move.rapid else move.kind
            centre, turns = None, 0
            if move.centre_m is not None:
                turns = int(
                    math.copysign(max(1, math.ceil(abs(sweep) / (2.0 * math.pi) - 1e-3)), sweep)
                )  # 1e-3: pieces
                centre = (move.centre_m[0] * 1e3, move.centre_m[1] * 1e3) if whole else None
            points.append(Point(kind, move.end_m[0] * 1e3, move.end_m[1] * 1e3, line=move.line, centre=centre,
                                turns=turns))  # fmt: skip
            sweep = 0.0
        whole = not move.piece
    return tuple(points)


@dataclass(frozen=True)
class Comparison:
    """The walk of :func:`compare`: agreed, how many points matched, the worst distance of two ends (mm), and
    where the two first disagree (empty when they agree)."""

    agreed: bool
    matched: int
    worst_mm: float
    disagreement: str = ""


def compare(rs274: tuple[Point, ...], twin: tuple[Point, ...]) -> Comparison:
    """Walk rs274's points beside the reader's (this module's docstring): same ends, same order, within
    :data:`TOLERANCE_MM`.

    Each point of one path is matched by the next of the other, except a point that leaves X Y where they
    are: rs274's within :data:`SAME_POINT_MM` of its last matched point (Z only, or a line to where it is),
    the reader's within :data:`READER_SAME_MM` of its own (rs274 prints rounded and may print such a move as
    one or as none). Either may also have a partner: the walk goes on with the best alignment (more matched
    points, then a smaller worst distance) at each point of the reader's that one has reached, at most
    :data:`ALIGNMENTS_MAX` of them (those that matched the most, then got furthest), and gives the best that
    gets to both ends, or the disagreement nearest to agreeing. (An exhaustive search may find an agreeing
    alignment this walk does not, in runs of moves under 0.35 um on both sides: rarely.)"""
    origin = (0.0, 0.0)  # rs274 starts at the origin, offsets 0
    j = 1 if twin and math.dist((twin[0].x, twin[0].y), origin) <= TOLERANCE_MM["mm"] else 0
    walks = [_Walk(j, 0.0, 0, origin, (twin[0].x, twin[0].y) if j else origin)]
    unit = "mm"
    for point in rs274:
        unit = point.unit
        after: dict[tuple, _Walk] = {}
        misses: list[tuple[float, _Walk, str]] = []
        for walk in _reader_skips(walks, twin, READER_SAME_MM[unit]):
            j = walk.j
            if point.x is None:  # a spline: its end is the reader's
                if j < len(twin):
                    end = (twin[j].x, twin[j].y)
                    _keep(after, _Walk(j + 1, walk.worst, walk.matched + 1, end, end))
                else:
                    misses.append((math.inf, walk, f"rs274 line {point.line}: a spline the reader does not make"))
                continue
            here = (point.x, point.y)
            if point.kind != "arc" and math.dist(here, walk.last) <= SAME_POINT_MM[unit]:
                _keep(after, walk)  # no XY motion (an arc back to its start is a circle)
            if j >= len(twin):
                misses.append((math.inf, walk, f"rs274 line {point.line}: {point.kind} to ({point.x:.4f}, "
                                               f"{point.y:.4f}) mm; the reader has no more moves"))  # fmt: skip
                continue
            other = twin[j]
            distance, what = _mismatch(point, other)
            if what:
                misses.append((distance, walk, what))
            else:
                _keep(after, _Walk(j + 1, max(walk.worst, distance), walk.matched + 1, here, (other.x, other.y)))
        if not after:
            distance, walk, what = min(misses, key=lambda miss: miss[0])
            worst = max(walk.worst, distance) if math.isfinite(distance) else walk.worst
            return Comparison(False, walk.matched, worst, what)
        walks = _best(after.values())
    walks = _reader_skips(walks, twin, READER_SAME_MM[unit])
    ended = [walk for walk in walks if walk.j == len(twin)]
    if ended:
        walk = ended[0]  # the best (:func:`_best`'s order)
        return Comparison(True, walk.matched, walk.worst)
    walk = max(walks, key=lambda w: w.j)
    other = twin[walk.j]
    return Comparison(False, walk.matched, walk.worst, f"the reader's {other.kind} of line {other.line} to "
                      f"({other.x:.4f}, {other.y:.4f}) mm: rs274 has no more moves")  # fmt: skip


@dataclass(frozen=True)
class _Walk:
    """One alignment of :func:`compare` so far: the reader's next point, its worst distance (mm) and matched
    points, and the last matched point of each path (mm)."""

    j: int
    worst: float
    matched: int
    last: tuple[float, float]
    reader_last: tuple[float, float]

    @property
    def key(self) -> tuple:
        """Of two alignments at one point of the reader's, only the better goes on."""
        return (self.j,)

    @property
    def rank(self) -> tuple:
        """Better first: more matched points, a smaller worst distance, further along the reader's path."""
        return (-self.matched, self.worst, -self.j)


def _keep(walks: dict[tuple, _Walk], walk: _Walk) -> None:
    """Keep ``walk`` unless one with its key is as good."""
    held = walks.get(walk.key)
    if held is None or walk.rank < held.rank:
        walks[walk.key] = walk


def _best(walks) -> list[_Walk]:
    """The :data:`ALIGNMENTS_MAX` best of ``walks``, best first."""
    return sorted(walks, key=lambda walk: walk.rank)[:ALIGNMENTS_MAX]


def _reader_skips(walks: list[_Walk], twin: tuple[Point, ...], same_mm: float) -> list[_Walk]:
    """``walks`` and the alignments that also leave out the reader's next points that do not move X Y (within
    ``same_mm`` of its last matched point; never an arc): one pass along the reader's points, each keeping its
    best alignment (:func:`_keep`); :func:`_best` of them."""
    out: dict[tuple, _Walk] = {}
    for walk in walks:
        _keep(out, walk)
    j, last = min(w.j for w in walks), max(w.j for w in walks)
    while j <= last:
        walk = out.get((j,))
        if walk is not None and j < len(twin) and twin[j].kind != "arc" and math.dist(
            (twin[j].x, twin[j].y), walk.reader_last) <= same_mm:  # fmt: skip
            _keep(out, dataclasses.replace(walk, j=j + 1))
            last = max(last, j + 1)
        j += 1
    return _best(out.values())


def _mismatch(point: Point, other: Point) -> tuple[float, str]:
    """The distance of rs274's ``point`` from the reader's ``other`` (mm) and why they are not one ("" when
    they are: the same end within the tolerance, and for two arcs the same turns and centre)."""
    tolerance = TOLERANCE_MM[point.unit]
    distance = math.dist((point.x, point.y), (other.x, other.y))
    if distance > tolerance:
        return distance, (
            f"rs274 line {point.line}: {point.kind} to ({point.x:.4f}, {point.y:.4f}) mm; the reader's "
            f"{other.kind} of line {other.line} to ({other.x:.4f}, {other.y:.4f}) mm ({distance * 1e3:.1f} um)"
        )  # fmt: skip
    what = ""
    if point.kind == "arc" and other.kind == "arc":
        if point.turns != other.turns:
            what = f"turns {other.turns} (rs274: {point.turns}, + counter-clockwise)"
        elif point.centre is not None and other.centre is not None:
            miss = math.dist(point.centre, other.centre)
            if miss > tolerance + point.slack:
                what = (f"centre ({other.centre[0]:.4f}, {other.centre[1]:.4f}) mm "
                        f"({miss * 1e3:.1f} um from rs274's)")  # fmt: skip
    if what:
        return distance, f"rs274 line {point.line}: the reader's arc of line {other.line} has {what}"
    return distance, ""
