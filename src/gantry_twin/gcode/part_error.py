"""The part error: how far an actual trajectory is from the programmed lines and arcs.

Unlike eps_c (the distance to the *planned* path, blends included), the
part error is measured against the program's own geometry, exactly (the
distance to a line segment or to an arc, :meth:`MoveTable.distance`), so
it includes the deviation the blends allow (G64 P). A sample is measured
against the feed moves around the one being run (it and ``neighbours``
moves each side), so that a pocket's neighbouring passes do not hide its
error; rapids are left out unless asked for.

Per block: max and rms error, time spent, feed achieved (mean actual speed)
against the programmed F. Per corner (a junction of two feed moves): max
error within ``corner_window_s`` of the corner's blend or stop, the actual
speed when nearest the corner point and when that is. Docs: docs/gcode.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gantry_twin.gcode.sampling import ProgramPath


@dataclass(frozen=True)
class BlockError:
    """One feed move: source line, max / rms part error m, time spent s, feed achieved and programmed m/s."""

    line: int
    move: int
    max_m: float
    rms_m: float
    time_s: float
    feed_achieved_m_s: float
    feed_programmed_m_s: float


@dataclass(frozen=True)
class CornerError:
    """The junction after move ``move`` (source line ``line``): its kind, point, turn, max error, speed, time."""

    line: int
    move: int
    kind: str
    point_m: tuple[float, float]
    turn_rad: float
    max_m: float
    speed_m_s: float
    time_s: float


@dataclass(frozen=True)
class PartError:
    """The part error of a trajectory: per sample (NaN where not measured), per block, per corner, totals."""

    distance_m: np.ndarray
    blocks: tuple[BlockError, ...]
    corners: tuple[CornerError, ...]
    cycle_time_s: float
    max_m: float
    rms_m: float
    feed_achieved_m_s: float


def distance_to_program(
    plan: ProgramPath, move: np.ndarray, q_m: np.ndarray, neighbours: int = 2, rapids: bool = False
):
    """Distance of q[i] to the programmed moves move[i] - neighbours .. move[i] + neighbours (feed moves only
    unless ``rapids``), m; NaN during a rapid (unless ``rapids``)."""
    return _nearest_moves(plan, move, q_m, neighbours, rapids)[0]


def nearest_on_program(plan: ProgramPath, move: np.ndarray, q_m: np.ndarray, neighbours: int = 2, rapids: bool = False):
    """(distance m (n,), nearest programmed point m (n, 2)) of q[i] among the moves :func:`distance_to_program`
    measures against; NaN where it measures nothing (a rapid)."""
    distance, k = _nearest_moves(plan, move, q_m, neighbours, rapids)
    q = np.asarray(q_m, dtype=float).reshape(-1, 2)
    point = np.full_like(q, np.nan)
    found = k >= 0
    if found.any():
        point[found] = plan.table.nearest(k[found], q[found])
    return distance, point


def _nearest_moves(plan: ProgramPath, move: np.ndarray, q_m: np.ndarray, neighbours: int, rapids: bool):
    """The distance of each q[i] to its nearest counted move and that move's index (-1 and NaN: none)."""
    table = plan.table
    counted = np.ones(len(plan.moves), dtype=bool) if rapids else ~plan.rapid
    q = np.asarray(q_m, dtype=float).reshape(-1, 2)
    best = np.full(len(q), np.inf)
    which = np.full(len(q), -1)
    own = counted[np.clip(move, 0, table.count - 1)]
    for offset in range(-neighbours, neighbours + 1):
        k = move + offset
        valid = (k >= 0) & (k < table.count)
        kk = np.clip(k, 0, table.count - 1)
        valid &= counted[kk] & own
        if valid.any():
            d = table.distance(kk[valid], q[valid])
            closer = d < best[valid]
            rows = np.flatnonzero(valid)[closer]
            best[rows], which[rows] = d[closer], kk[valid][closer]
    return np.where(np.isfinite(best), best, np.nan), which


def part_error(
    plan: ProgramPath,
    t_s: np.ndarray,
    q_m: np.ndarray,
    neighbours: int = 2,
    corner_window_s: float = 0.01,
    rapids: bool = False,
) -> PartError:
    """The part error of positions q_m (n, 2) at times t_s (n,) of a run of ``plan``."""
    t = np.asarray(t_s, dtype=float).reshape(-1)
    q = np.asarray(q_m, dtype=float).reshape(-1, 2)
    move = plan.sample(t).move
    distance = distance_to_program(plan, move, q, neighbours, rapids)
    speed = np.zeros(len(t))
    if len(t) > 1:
        step = np.linalg.norm(np.diff(q, axis=0), axis=1) / np.diff(t)
        speed[1:-1] = 0.5 * (step[:-1] + step[1:])
        speed[0], speed[-1] = step[0], step[-1]
    blocks = []
    for k, m in enumerate(plan.moves):
        if m.rapid and not rapids:
            continue
        rows = move == k
        d = distance[rows]
        d = d[np.isfinite(d)]
        time_s = float(rows.sum() * (t[1] - t[0])) if len(t) > 1 else 0.0
        blocks.append(
            BlockError(
                line=m.line, move=k, max_m=float(d.max()) if d.size else 0.0,
                rms_m=float(np.sqrt(np.mean(d**2))) if d.size else 0.0, time_s=time_s,
                feed_achieved_m_s=float(speed[rows].mean()) if rows.any() else 0.0,
                feed_programmed_m_s=float(m.feed_m_s),
            )
        )  # fmt: skip
    corners = []
    kinds = {0: "stop", 1: "pass", 2: "blend"}
    for k in range(1, len(plan.moves)):
        a, b = plan.moves[k - 1], plan.moves[k]
        if a.rapid or b.rapid:
            continue
        start = min(plan.t0_s[k], plan.end_s[k - 1]) - corner_window_s
        stop = max(plan.t0_s[k], plan.end_s[k - 1]) + corner_window_s
        rows = np.flatnonzero((t >= start) & (t <= stop))
        point = plan.table.end[k - 1]
        if rows.size == 0:
            continue
        near = rows[np.argmin(np.linalg.norm(q[rows] - point, axis=1))]
        d = distance[rows]
        corners.append(
            CornerError(
                line=a.line, move=k - 1, kind=kinds[int(plan.kind[k])], point_m=(float(point[0]), float(point[1])),
                turn_rad=float(abs(plan.alpha_start[k] - plan.alpha_end[k - 1])),
                max_m=float(np.nanmax(d)) if np.isfinite(d).any() else 0.0,
                speed_m_s=float(speed[near]), time_s=float(t[near]),
            )
        )  # fmt: skip
    measured = distance[np.isfinite(distance)]
    feed_rows = np.isin(move, [b.move for b in blocks])
    return PartError(
        distance_m=distance,
        blocks=tuple(blocks),
        corners=tuple(corners),
        cycle_time_s=plan.duration_s,
        max_m=float(measured.max()) if measured.size else 0.0,
        rms_m=float(np.sqrt(np.mean(measured**2))) if measured.size else 0.0,
        feed_achieved_m_s=float(speed[feed_rows].mean()) if feed_rows.any() else 0.0,
    )


#: Blocks and corners listed in summary.json's ``part_error`` (the worst first); the totals count all of them.
LISTED_MAX = 50


class PartErrorWatch:
    """An Observer that keeps a run's true positions and gives its :func:`part_error` as summary.json's
    ``part_error`` section (:meth:`summary`): totals in um, the worst blocks and corners."""

    def __init__(self, plan: ProgramPath) -> None:
        self.plan = plan
        self._t: list[np.ndarray] = []
        self._q: list[np.ndarray] = []

    def on_start(self, run: object, trace: object) -> None:
        pass

    def on_chunk(self, trace: object, start: int, stop: int) -> None:
        rows = slice(start - trace.first, stop - trace.first)
        self._t.append(trace.t_s[rows].copy())
        self._q.append(trace.q_m[rows].copy())

    def on_end(self, trace: object) -> None:
        pass

    def summary(self) -> dict | None:
        if not self._t:
            return None
        result = part_error(self.plan, np.concatenate(self._t), np.concatenate(self._q))
        blocks = sorted(result.blocks, key=lambda b: -b.max_m)[:LISTED_MAX]
        corners = sorted(result.corners, key=lambda c: -c.max_m)[:LISTED_MAX]
        return {
            "max_um": 1e6 * result.max_m,
            "rms_um": 1e6 * result.rms_m,
            "cycle_time_s": result.cycle_time_s,
            "feed_achieved_m_s": result.feed_achieved_m_s,
            "blocks": len(result.blocks),
            "corners": len(result.corners),
            "worst_blocks": [
                {"line": b.line, "max_um": 1e6 * b.max_m, "rms_um": 1e6 * b.rms_m, "time_s": b.time_s,
                 "feed_achieved_m_s": b.feed_achieved_m_s, "feed_programmed_m_s": b.feed_programmed_m_s}
                for b in blocks
            ],
            "worst_corners": [
                {"line": c.line, "kind": c.kind, "point_m": list(c.point_m), "turn_rad": c.turn_rad,
                 "max_um": 1e6 * c.max_m, "speed_m_s": c.speed_m_s, "time_s": c.time_s}
                for c in corners
            ],
            "messages": list(self.plan.program.messages),
            "dropped": dict(self.plan.program.dropped),
            "merged": self.plan.program.merged,
        }  # fmt: skip
