"""What ``gantry-twin validate PROGRAM.ngc`` prints: a program read and planned, without simulating it.

Moves (feed and rapid), path length, planned time, the fraction of the feed
moves' time spent at the programmed feed (within 1 %, the plan sampled
every millisecond or finer), the words dropped and the G1 lines merged by
G64 Q, and the extent against the machine's travel. A program without XY
moves (one that only computes and prints, or only moves Z) is read and
reported with 0 moves and no plan; ``run`` refuses it (nothing to run).
"""

from __future__ import annotations

import numpy as np

from gantry_twin.gcode.geometry import bounding_box
from gantry_twin.gcode.program import Program
from gantry_twin.gcode.sampling import Plan

#: A sample is "at the programmed feed" within this fraction of it.
AT_FEED_TOLERANCE = 0.01
#: Most samples taken of a plan for the fraction at feed.
MAX_SAMPLES = 200_000


def fraction_at_feed(plan: Plan) -> float:
    """The fraction of the feed moves' planned time at the programmed feed (nan: no feed move)."""
    dt = max(1e-3, plan.duration_s / MAX_SAMPLES)
    t = np.arange(0.0, plan.duration_s, dt)
    samples = plan.sample(t)
    feed = np.array([m.feed_m_s for m in plan.moves])
    move = samples.move
    rows = ~plan.rapid[move]
    if not rows.any():
        return float("nan")
    speed = np.hypot(samples.v_m_s[:, 0], samples.v_m_s[:, 1])
    at_feed = speed[rows] >= (1.0 - AT_FEED_TOLERANCE) * feed[move[rows]]
    return float(at_feed.mean())


def validation_lines(program: Program, plan: Plan | None, travel_half_m: tuple[float, float]) -> list[str]:
    """The summary of a program read and planned (``plan`` None: it has no XY move), one fact per line."""
    moves = program.moves
    rapid = sum(m.rapid for m in moves)
    length_feed = sum(m.length_m for m in moves if not m.rapid)
    length_rapid = sum(m.length_m for m in moves if m.rapid)
    lo, hi = bounding_box(moves) if moves else (np.array(program.start_m), np.array(program.start_m))
    fraction = fraction_at_feed(plan) if plan is not None else float("nan")
    dropped = ", ".join(f"{kind} {n}" for kind, n in sorted(program.dropped.items())) or "nothing"
    lines = [
        f"{program.name}: ok ({program.blocks} blocks executed)",
        f"  moves: {len(moves)} ({len(moves) - rapid} feed, {rapid} rapid)",
        f"  length: {length_feed * 1e3:.3f} mm at feed, {length_rapid * 1e3:.3f} mm rapid",
        f"  planned time: {plan.duration_s:.3f} s" if plan is not None else "  planned time: 0 s (no XY move to plan)",
        f"  at programmed feed: {'-' if fraction != fraction else f'{100.0 * fraction:.1f} %'} of the feed moves' time",
        f"  dropped: {dropped}",
        f"  merged (G64 Q): {program.merged} G1 line(s)",
    ]
    for axis, letter in enumerate("XY"):
        half = travel_half_m[axis]
        used = max(abs(lo[axis]), abs(hi[axis])) / half
        lines.append(
            f"  extent {letter}: {lo[axis] * 1e3:.3f} .. {hi[axis] * 1e3:.3f} mm of +-{half * 1e3:g} mm travel "
            f"({100.0 * used:.1f} % of the half travel)"
        )
    lines += [f"  {message}" for message in program.messages]
    return lines
