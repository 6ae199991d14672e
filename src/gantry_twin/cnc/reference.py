"""LinuxCNC's recorded commands as the loop's reference (a part program's path in time, phi = t).

LinuxCNC's X and Y joint commands, recorded at every servo period T
(:class:`~gantry_twin.cnc.offline.CncRecord`), are interpolated to the
twin's 0.2 ms samples by the cubic spline through them with zero velocity
at both ends (the machine starts and ends at rest; ``scipy.interpolate.CubicSpline``,
``bc_type="clamped"``): it passes through every recorded command exactly,
and q_d', q_d'' and q_d''' are its derivatives, so the reference's velocity
and acceleration are those of the position the loop tracks (C2: the
acceleration is continuous, the jerk piecewise constant). On a straight
line the spline stays on it (a spline reproduces every affine function).

The task frame's angle alpha (eq. 1) is the direction of q_d' where the
reference moves at ``DIRECTION_SPEED_M_S`` or faster, with alpha' =
(v x a) / |v|^2 and alpha'' its derivative (v x j / |v|^2 - 2 (v x a)(v . a)
/ |v|^4); slower, near a stop or a start, the direction of a velocity that
turns a corner within a millisecond says little, and alpha is the tangent
of the canonical move the sample is on, at its nearest point (alpha' = c v . T,
alpha'' = c a . T, c the move's curvature): at a corner where LinuxCNC
stops, alpha turns at once, at rest. alpha is unwrapped along the run.

The programmed path is the program as LinuxCNC's interpreter reads it
(:mod:`gantry_twin.cnc.canon`); each servo sample is attributed to the
canonical move it is on (:func:`attribute`), so that the part error
(:mod:`gantry_twin.gcode.part_error`) measures each sample against the
moves around its own, as it does for the twin's own plan. Docs: docs/linuxcnc.md.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from gantry_twin.cnc.canon import CanonProgram
from gantry_twin.cnc.config import CncMachine
from gantry_twin.cnc.offline import CncRecord
from gantry_twin.gcode.geometry import Move, MoveTable
from gantry_twin.gcode.program import Program
from gantry_twin.gcode.sampling import Samples, timed_contour_error
from gantry_twin.numerics import libm
from gantry_twin.paths.contours import Reference

#: LinuxCNC's side of a run directory: what it did (program time, messages, limits) and its recorded commands.
CNC_FILE, CNC_COMMANDS_FILE = "linuxcnc.json", "linuxcnc_commands.csv"
#: The columns of :data:`CNC_COMMANDS_FILE`: time from the program's start (s), the X and Y commands (m, machine
#: coordinates), the program line LinuxCNC's motion ran at (0: none).
COMMANDS_HEADER = "t_s,x_m,y_m,line"
#: From this speed on, alpha is the direction of the reference's velocity; below it, the tangent of its move (m/s).
DIRECTION_SPEED_M_S = 0.05
#: A junction is a stop when the command's speed nearest the corner is below this (m/s).
STOP_SPEED_M_S = 1e-3


class CncPath:
    """A program's path as LinuxCNC commanded it: the loop's :class:`~gantry_twin.paths.contours.TimedContour`
    and, for the part error, the canonical moves with the time each one ran (the attributes of
    :class:`~gantry_twin.gcode.sampling.ProgramPath`). ``rapid`` marks the moves the part error leaves out: rapids,
    and the stretches whose geometry rs274 does not print (splines)."""

    def __init__(self, record: CncRecord) -> None:
        self.record = record
        canon = record.canon
        self.servo_t_s = record.t_s
        self.duration_s = float(record.t_s[-1])
        self._spline = CubicSpline(record.t_s, record.q_m, bc_type="clamped")
        moves = canon.moves or [Move("line", tuple(record.q_m[0]), tuple(record.q_m[0]), math.inf, True, 0)]
        self.table = MoveTable(moves)
        move_index = [i for i, item in enumerate(canon.items) if isinstance(item, Move)]
        unjudged = {k for k, i in enumerate(move_index) if i in canon.unjudged}
        self.servo_move = attribute(self.table, record.q_m, unjudged)
        self.moves = moves = [_with_line(m, record.line[self.servo_move == k]) for k, m in enumerate(moves)]
        self.true_rapid = np.array([m.rapid for m in moves], dtype=bool)
        self._unmeasurable = self.true_rapid | np.array([k in unjudged for k in range(len(moves))], dtype=bool)
        self.rapid = self._unmeasurable.copy()
        dropped = {"spline or other-plane moves not judged": len(unjudged)} if unjudged else {}
        if self.out_of_step_m() > OUT_OF_STEP_M:  # the attribution lost its way: judge nothing rather than wrongly
            self.rapid[:] = True
            dropped = {"moves not judged: LinuxCNC's commands could not be matched to them in order": len(moves)}
        self.program = Program(
            name=canon.name, items=canon.items, start_m=(float(record.q_m[0, 0]), float(record.q_m[0, 1])),
            dropped=dropped, messages=(*canon.messages, *record.messages), programmed_moves=tuple(moves),
        )  # fmt: skip
        self._alpha_servo = self._servo_alpha()
        n = self.table.count
        first = np.searchsorted(self.servo_move, np.arange(n), side="left")
        last = np.searchsorted(self.servo_move, np.arange(n), side="right") - 1
        self.t0_s = record.t_s[np.clip(first, 0, len(record.t_s) - 1)]
        self.end_s = record.t_s[np.clip(np.maximum(last, first), 0, len(record.t_s) - 1)]
        speed = np.linalg.norm(self._spline(record.t_s, 1), axis=1)
        self.kind = np.full(n, 2, dtype=int)  # a junction after move k - 1: blend unless LinuxCNC stopped there
        for k in range(1, n):
            rows = slice(max(last[k - 1], 0), max(first[k], 0) + 1)
            if speed[rows].size and speed[rows].min() < STOP_SPEED_M_S:
                self.kind[k] = 0
        self.alpha_start = np.array([m.tangent_angle(0.0) for m in moves])
        self.alpha_end = np.array([m.tangent_angle(m.length_m) for m in moves])

    def out_of_step_m(self) -> float:
        """The largest distance of a command to the judged move it is attributed to (m): within the program's
        blending tolerance when the attribution is right; far more when it lost its way (a program whose XY path
        retraces one line again and again, as a lathe program in XZ does)."""
        judged = ~self._unmeasurable[self.servo_move]
        if not judged.any():
            return 0.0
        return float(self.table.distance(self.servo_move[judged], self.record.q_m[judged]).max())

    def run_files(self) -> dict[str, str]:
        """LinuxCNC's side of the run directory (:data:`CNC_FILE`, :data:`CNC_COMMANDS_FILE`): name -> text."""
        record, machine = self.record, self.record.machine
        info = {
            "cnc": "linuxcnc",
            "program": self.program.name,
            "program_time_s": record.program_time_s,
            "servo_period_s": record.servo_period_s,
            "samples": len(record.t_s),
            "messages": list(record.messages),
            "canonical_moves": len(self.moves),
            "moves_not_judged": int(np.count_nonzero(self.rapid & ~self.true_rapid)),
            "splines": record.canon.splines,
            "machine": {
                "source": machine.source,
                "travel_mm": [list(machine.travel_mm[0]), list(machine.travel_mm[1])],
                "velocity_mm_s": list(machine.velocity_mm_s),
                "acceleration_mm_s2": list(machine.acceleration_mm_s2),
                "traj_velocity_mm_s": machine.traj_velocity_mm_s,
                "traj_acceleration_mm_s2": machine.traj_acceleration_mm_s2,
                "following_error_mm": list(machine.following_error_mm),
            },
        }
        rows = "\n".join(
            f"{t:.6f},{x:.9f},{y:.9f},{line}"
            for t, (x, y), line in zip(record.t_s, record.q_m, record.line, strict=True)
        )
        return {CNC_FILE: json.dumps(info, indent=2) + "\n", CNC_COMMANDS_FILE: f"{COMMANDS_HEADER}\n{rows}\n"}

    # ------------------------------------------------------------------ the loop's reference (phi = t)
    @property
    def period_rad(self) -> float:
        return self.duration_s

    def derivatives(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        t = np.clip(np.asarray(phi, dtype=float), 0.0, self.duration_s)
        return tuple(self._spline(t, order) for order in range(4))  # type: ignore[return-value]

    def reference(self, t_s: np.ndarray) -> Reference:
        return self.sample(t_s).reference()

    def contour_error(self, q_m: np.ndarray, phi_guess: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """eps_c against the commanded path (:func:`~gantry_twin.gcode.sampling.timed_contour_error`)."""
        return timed_contour_error(self.sample, self.duration_s, q_m, phi_guess)

    def rapid_spans(self) -> list[tuple[float, float]]:
        """(start, end) s of each rapid (G0) move: left out of the contour figures, as for the twin's plan."""
        return [(float(self.t0_s[k]), float(self.end_s[k])) for k in np.flatnonzero(self.true_rapid)]

    def sample(self, t_s: np.ndarray) -> Samples:
        """The reference at times t_s (s; held at the ends outside [0, duration])."""
        t = np.asarray(t_s, dtype=float).reshape(-1)
        tc = np.clip(t, 0.0, self.duration_s)
        q, v, a, j = (self._spline(tc, order) for order in range(4))
        outside = (t < 0.0) | (t > self.duration_s)
        v[outside], a[outside], j[outside] = 0.0, 0.0, 0.0
        servo = np.clip(np.rint(tc / self.record.servo_period_s).astype(int), 0, len(self.servo_t_s) - 1)
        alpha, dalpha, ddalpha = self._alpha(q, v, a, j, self.servo_move[servo], self._alpha_servo[servo])
        return Samples(t, q, v, a, j, alpha, dalpha, ddalpha, self.servo_move[servo])

    def _servo_alpha(self) -> np.ndarray:
        """alpha at the servo instants, unwrapped along the run."""
        t = self.servo_t_s
        q, v, a, j = (self._spline(t, order) for order in range(4))
        raw = self._alpha(q, v, a, j, self.servo_move, np.zeros(len(t)))[0]
        return np.unwrap(raw)

    def _alpha(self, q, v, a, j, k, near):
        """alpha (continued from ``near``, its value at the nearest servo instant) and its two rates: from the
        velocity where the reference moves at DIRECTION_SPEED_M_S or more, else from the tangent of its move at
        the nearest point (alpha' = c (v . T), alpha'' = c (a . T), c the move's signed curvature)."""
        table = self.table
        arc = table.is_arc[k]
        rel = q - table.centre[k]
        along_arc = libm.atan2(rel[:, 1], rel[:, 0]) + table.sign[k] * 0.5 * np.pi
        along_line = libm.atan2(table.direction[k, 1], table.direction[k, 0])
        geometric = np.where(arc, along_arc, along_line)
        tangent = np.stack([libm.cos(geometric), libm.sin(geometric)], axis=-1)
        c = table.curvature[k]
        speed2 = np.einsum("ij,ij->i", v, v)
        moving = speed2 >= DIRECTION_SPEED_M_S**2
        raw = np.where(moving, libm.atan2(v[:, 1], v[:, 0]), geometric)
        alpha = near + np.mod(raw - near + np.pi, 2 * np.pi) - np.pi
        cross_a = v[:, 0] * a[:, 1] - v[:, 1] * a[:, 0]
        cross_j = v[:, 0] * j[:, 1] - v[:, 1] * j[:, 0]
        safe = np.where(moving, speed2, 1.0)
        dot = np.einsum("ij,ij->i", v, a)
        dalpha = np.where(moving, cross_a / safe, c * np.einsum("ij,ij->i", v, tangent))
        ddalpha = np.where(
            moving, (cross_j * safe - 2.0 * cross_a * dot) / safe**2, c * np.einsum("ij,ij->i", a, tangent)
        )
        return alpha, dalpha, ddalpha


def read_run_files(run_dir: Path, canon: CanonProgram) -> CncRecord:
    """The record a run wrote (:meth:`CncPath.run_files`: :data:`CNC_FILE`, :data:`CNC_COMMANDS_FILE` in
    ``run_dir``) with ``canon``, its program read by rs274 again: ``CncPath(read_run_files(...))`` is the path
    the run followed (its commands to 1 nm). ValueError in one line naming the file for a file that is not one
    a run wrote, or a program that no longer has the run's moves; OSError when one cannot be read."""
    info_path, commands_path = run_dir / CNC_FILE, run_dir / CNC_COMMANDS_FILE
    try:
        info = json.loads(info_path.read_text(encoding="utf-8"))
        m = info["machine"]
        period_s = float(info["servo_period_s"])
        if not 0.0 < period_s < 1.0:
            raise ValueError(f"servo_period_s is {period_s!r}, not a period from 0 to 1 s")
        if not isinstance(info["messages"], list) or not all(isinstance(t, str) for t in info["messages"]):
            raise ValueError("messages is not a list of texts")
        machine = CncMachine(
            travel_mm=(tuple(m["travel_mm"][0]), tuple(m["travel_mm"][1])), velocity_mm_s=tuple(m["velocity_mm_s"]),
            acceleration_mm_s2=tuple(m["acceleration_mm_s2"]), traj_velocity_mm_s=float(m["traj_velocity_mm_s"]),
            traj_acceleration_mm_s2=float(m["traj_acceleration_mm_s2"]), servo_period_ns=round(period_s * 1e9),
            following_error_mm=tuple(m["following_error_mm"]), source=str(m["source"]),
        )  # fmt: skip
        program_time_s, moves, samples = (
            float(info["program_time_s"]),
            int(info["canonical_moves"]),
            int(info["samples"]),
        )
    except (ValueError, KeyError, TypeError, IndexError, OverflowError) as exc:
        raise ValueError(f"{info_path}: not a run's {CNC_FILE} ({type(exc).__name__}: {exc})") from None
    if moves != max(len(canon.moves), 1):
        raise ValueError(f"{canon.name}: rs274 reads {len(canon.moves)} moves of it now, the run had {moves} "
                         "(the program changed since the run)")  # fmt: skip
    with open(commands_path, encoding="utf-8") as file, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numpy's warning on an empty file: the check below says it
        header = file.readline().strip()
        if header != COMMANDS_HEADER:
            raise ValueError(f"{commands_path}: its first line is {header[:60]!r}, not {COMMANDS_HEADER!r}")
        try:
            rows = np.loadtxt(file, delimiter=",", ndmin=2)
        except ValueError as exc:
            raise ValueError(f"{commands_path}: {str(exc).splitlines()[0]}") from None
    if rows.shape[0] != samples or samples < 2 or rows.shape[1] != 4 or not np.isfinite(rows).all():
        raise ValueError(f"{commands_path}: not {samples} finite rows of 4 columns ({CNC_FILE}'s samples)")
    line = rows[:, 3]
    if np.any(np.diff(rows[:, 0]) <= 0) or np.any(line != np.round(line)) or np.any(line < 0):
        raise ValueError(f"{commands_path}: its times do not increase or a line is not a whole number >= 0")
    messages = tuple(info["messages"])
    return CncRecord(t_s=rows[:, 0], q_m=rows[:, 1:3], line=line.astype(np.int64), servo_period_s=period_s,
                     program_time_s=program_time_s, messages=messages, canon=canon, machine=machine)  # fmt: skip


def _with_line(move: Move, lines: np.ndarray) -> Move:
    """``move`` with the source line LinuxCNC's motion reported most while running it (rs274 prints none)."""
    lines = lines[lines > 0]
    if lines.size == 0:
        return replace(move, line=0)
    values, counts = np.unique(lines, return_counts=True)
    return replace(move, line=int(values[np.argmax(counts)]))


def attribute(table: MoveTable, q_m: np.ndarray, unjudged: frozenset[int] | set[int] = frozenset()) -> np.ndarray:
    """The canonical move each command sample q_m[i] is on (n,), in order.

    The command runs the moves in order. A sample stays on move k until it
    has covered at least half of k's length (LinuxCNC blends within half a
    move) and is nearer move k + 1 than k, or has covered all of it and is
    no farther from k + 1 (a move that retraces k, a full circle's end). The
    covered length is the command's own path length since k began, so that
    a full circle (it starts and ends at the same point) is told from the
    move after it. An ``unjudged`` move's
    path is unknown (a spline, an arc in another plane) but not its end: the
    command stays on it until it has come within ``END_TOLERANCE_M`` of that
    end and come no nearer.
    """
    q = np.asarray(q_m, dtype=float).reshape(-1, 2)
    n, count = len(q), table.count
    out = np.full(n, count - 1, dtype=np.int64)
    if count == 1:
        out[:] = 0
        return out
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])
    i = 0
    for k in range(count - 1):
        if i >= n:
            break
        if k in unjudged:
            j = _past_end(q, i, table.end[k])
        else:
            length = float(table.length[k])
            stop = int(np.searchsorted(s, s[i] + 1.5 * length + 2e-3, side="right")) + 1
            stop = min(max(stop, i + 2), n)
            rows = np.arange(i, stop)
            covered = s[rows] - s[i]
            d_here = table.distance(np.full(len(rows), k), q[rows])
            d_next = table.distance(np.full(len(rows), k + 1), q[rows])
            half = (covered >= 0.5 * length - 1e-9) & (d_next < d_here - NEARER_M)
            whole = (covered >= length - COVERED_SLACK_M) & (d_next <= d_here + NEARER_M)
            switch = np.flatnonzero(half | whole)
            j = int(rows[switch[0]]) if switch.size else stop
        out[i:j] = k
        i = j
    return out


#: A command farther than this from its judged move means the attribution lost its way (m; G64 P is far less).
OUT_OF_STEP_M = 1e-3
#: Nearer by less than this is a tie (two moves over the same points differ by rounding only), m.
NEARER_M = 1e-10
#: The command has covered a move when its path since the move began is this much short of the move's length (m).
COVERED_SLACK_M = 1e-7
#: How near the command must come to an unjudged move's end point to have reached it (m).
END_TOLERANCE_M = 5e-5


def _past_end(q: np.ndarray, i: int, end: np.ndarray) -> int:
    """The first sample after the command, from sample i on, arrived within END_TOLERANCE_M of ``end`` and then came
    no nearer (len(q) if it never does). A stretch that starts at its end point must first leave it: an arrival is
    a coming back (a lathe-like program in XZ passes the same X again and again)."""
    d = np.linalg.norm(q[i:] - end, axis=1)
    start = 0
    if d[0] < END_TOLERANCE_M:
        away = np.flatnonzero(d > 2 * END_TOLERANCE_M)
        if away.size == 0:
            return len(q)
        start = int(away[0])
    near = np.flatnonzero(d[start:] < END_TOLERANCE_M)
    if near.size == 0:
        return len(q)
    j = start + int(near[0])
    while j + 1 < len(d) and d[j + 1] <= d[j]:
        j += 1
    return i + j + 1
