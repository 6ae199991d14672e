"""Feed planning: a program's moves -> a jerk-limited reference for the 0.2 ms loop.

Each move is run by a 1-D jerk-limited profile u(t) along its arc length
(:mod:`gantry_twin.gcode.profiles`): a ramp in from rest to the entry
junction speed, a rise to the highest speed the move allows, a cruise, a
fall to the exit junction speed, a ramp out to rest. The junction speeds
come from a look-ahead over all blocks (backward then forward) so that the
machine can always stop at the end.

A corner is *blended by superposition*: the next move's ramp in runs at
the same time as this move's ramp out, mirrored (same speed, limits and
duration), so the speeds add up to the junction speed and the two motions'
displacements add up to a smooth path through the corner. The reference is
then C2 with bounded jerk everywhere, also at tangent line-arc junctions
(where the curvature jump of the program is smoothed the same way). The
blend stays within G64 P of the programmed moves by the bound

    deviation <= 2 s_h sin(theta / 2) + s_h (s_h / 2 + d) (k_A + k_B)

(s_h: the length of the ramp's first half, d: the ramp's length, theta the
turn, k the curvatures), which caps the junction speed. At G61, at turns of
more than ``blend_angle_max_rad``, at a dwell and around a rapid the
machine stops at the corner point.

Per-axis limits hold by construction: a line's path limits are the axis
limits divided by |direction_i|; an arc's path speed keeps its centripetal
acceleration and jerk at a fraction of the axis limits; a blend's
acceleration and jerk are bounded by the ramp's times |t_B - t_A|_i plus
the centripetal terms.

alpha'' stays finite: on a move alpha' = k u' and alpha'' = k u''; in a
blend the speed is at least v_c cos(theta / 2) > 0 (v_c >=
``blend_speed_min_m_s``, theta <= ``blend_angle_max_rad``), so alpha' =
(v x a) / |v|^2 and alpha'' = ((v x j)|v|^2 - 2 (v x a)(v . a)) / |v|^4 are
bounded; at a stop the reference stands still while alpha turns to the
next direction by a quintic smoothstep over ``pivot_s``. Docs: docs/gcode.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gantry_twin.gcode.geometry import Dwell, MoveTable
from gantry_twin.gcode.profiles import (
    half_ramp_distance,
    peak_speed,
    ramp_distance,
    ramp_phases,
    ramp_time,
    reach_speed,
)
from gantry_twin.gcode.reader import GcodeError, Program
from gantry_twin.gcode.sampling import Plan
from gantry_twin.numerics import libm
from gantry_twin.settings import VOLTS_MAX_V

#: The motors' force constant (models/gantry.xml: gear = kf), N/V.
FORCE_PER_VOLT_N_V = 69.0
#: Moving masses of the X carriage and of the Y axis with X on it (models/gantry.xml), kg.
MOVING_MASS_KG = (8.28, 34.5)
#: Share of the peak force the plan may use for acceleration: the rest is kept for friction,
#: disturbances and feedback.
FORCE_SHARE = 0.5
#: Time from zero to the acceleration limit at the jerk limit, s.
JERK_RISE_S = 0.02
#: Path speed limit of each axis, m/s (twice the paper's fastest contour speed, 0.6 m/s on the ellipse, rounded).
SPEED_MAX_M_S = 1.0


@dataclass(frozen=True)
class AxisLimits:
    """Per-axis (X, Y) limits of the reference: speed m/s, acceleration m/s^2, jerk m/s^3."""

    velocity_m_s: tuple[float, float]
    acceleration_m_s2: tuple[float, float]
    jerk_m_s3: tuple[float, float]

    def __post_init__(self) -> None:
        for name in ("velocity_m_s", "acceleration_m_s2", "jerk_m_s3"):
            values = getattr(self, name)
            if len(values) != 2 or not all(math.isfinite(v) and v > 0 for v in values):
                raise ValueError(f"limits.{name}: two finite numbers > 0 (X, Y), got {values!r}")


def default_limits(
    volts_v: float = VOLTS_MAX_V,
    force_per_volt_n_v: float = FORCE_PER_VOLT_N_V,
    moving_mass_kg: tuple[float, float] = MOVING_MASS_KG,
    force_share: float = FORCE_SHARE,
    jerk_rise_s: float = JERK_RISE_S,
    speed_m_s: float = SPEED_MAX_M_S,
) -> AxisLimits:
    """a_i = share * volts * kf / m_i (half the +-10 V force: 41.7 m/s^2 on X, 10 on Y), j_i = a_i / rise."""
    accel = tuple(force_share * volts_v * force_per_volt_n_v / m for m in moving_mass_kg)
    return AxisLimits((speed_m_s, speed_m_s), accel, tuple(a / jerk_rise_s for a in accel))


@dataclass(frozen=True)
class PlanOptions:
    """How to plan: limits for feed moves and rapids, and the corner rules (see the module docstring)."""

    limits: AxisLimits = field(default_factory=default_limits)
    rapid_limits: AxisLimits | None = None
    pivot_s: float = 0.02
    blend_angle_max_rad: float = 2.0 * math.pi / 3.0
    blend_speed_min_m_s: float = 1e-3
    hold_end_s: float = 0.0


#: A junction's kind: the machine stops there, passes straight through (same direction and curvature),
#: or blends by superposition.
STOP, PASS, BLEND = 0, 1, 2
#: How many times the ramp's rate limits may exceed the largest axis limit (nearly straight corners).
_RAMP_RATE_CAP = 1e3
#: A blend's ramp stays within this share of each move, and within this angle on an arc (rad).
_RAMP_SHARE = 0.25
_RAMP_ARC_RAD = 0.1


def _move_limits(table: MoveTable, feed: np.ndarray, rapid: np.ndarray, options: PlanOptions) -> tuple[np.ndarray, ...]:
    """Path speed, acceleration and jerk of each move's own profile that keep every axis within its limits."""
    out = []
    for limits, chosen in ((options.limits, ~rapid), (options.rapid_limits or options.limits, rapid)):
        vmax, amax, jmax = (np.asarray(x) for x in (limits.velocity_m_s, limits.acceleration_m_s2, limits.jerk_m_s3))
        comp = np.abs(table.direction)
        with np.errstate(divide="ignore"):
            line = [np.min(lim / comp, axis=1) for lim in (vmax, amax, jmax)]
        r = np.where(table.is_arc, table.radius, 1.0)
        vs = np.minimum.reduce(
            [np.full_like(r, vmax.min()), np.sqrt(0.5 * amax.min() * r), np.cbrt(0.25 * jmax.min() * r * r)]
        )
        speed_arc = np.minimum(vs, feed)
        accel_arc = np.minimum(amax.min() - speed_arc**2 / r, jmax.min() * r / (6.0 * speed_arc))
        jerk_arc = jmax.min() - speed_arc**3 / r**2 - 3.0 * speed_arc * accel_arc / r
        arc = table.is_arc
        out.append(
            (
                chosen,
                np.where(arc, speed_arc, np.minimum(line[0], feed)),
                np.where(arc, accel_arc, line[1]),
                np.where(arc, jerk_arc, line[2]),
            )
        )
    speed, accel, jerk = (np.where(out[0][0], out[0][i], out[1][i]) for i in (1, 2, 3))
    return speed, accel, jerk


def _blend_ramp(speed, jn: dict, limits: AxisLimits) -> tuple[np.ndarray, np.ndarray]:
    """The ramp's acceleration and jerk limits at junction speed ``speed`` that keep each axis within its limits."""
    amax, jmax = np.asarray(limits.acceleration_m_s2), np.asarray(limits.jerk_m_s3)
    k = jn["k_max"]
    spread = jn["spread"]  # (m, 2): |t_B - t_A|_i plus the arcs' rotation over the ramp
    with np.errstate(divide="ignore", invalid="ignore"):
        accel = np.min((amax - (speed * speed * k)[:, None]) / spread, axis=1)
        accel = np.minimum(accel, np.where(k > 0, jmax.min() / (6.0 * speed * k), np.inf))
        accel = np.minimum(accel, _RAMP_RATE_CAP * amax.max())
        jerk = np.min((jmax - (speed**3 * k * k + 3.0 * speed * k * accel)[:, None]) / spread, axis=1)
        jerk = np.minimum(jerk, _RAMP_RATE_CAP * jmax.max())
    return np.nan_to_num(accel, nan=0.0), np.nan_to_num(jerk, nan=0.0)


def _blend_fits(speed, jn: dict, limits: AxisLimits) -> np.ndarray:
    accel, jerk = _blend_ramp(speed, jn, limits)
    positive = (accel > 0) & (jerk > 0)
    accel, jerk = np.where(positive, accel, 1.0), np.where(positive, jerk, 1.0)
    d = 0.5 * speed * ramp_time(speed, accel, jerk)
    s_h = half_ramp_distance(speed, accel, jerk)
    deviation = 2.0 * s_h * libm.sin(0.5 * jn["turn"]) + s_h * (0.5 * s_h + d) * jn["k_sum"]
    return positive & (d <= jn["room"]) & (deviation <= jn["tolerance"])


def _blend_speeds(jn: dict, speed_max: np.ndarray, limits: AxisLimits, iterations: int = 60) -> np.ndarray:
    """The highest junction speed <= speed_max whose blend fits (bisection: the tests are monotone in speed)."""
    lo = np.zeros_like(speed_max)
    hi = speed_max.copy()
    top = _blend_fits(speed_max, jn, limits)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        ok = _blend_fits(mid, jn, limits)
        lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
    return np.where(top, speed_max, lo)


def plan_program(program: Program, options: PlanOptions | None = None) -> Plan:
    """Plan a program read by :func:`~gantry_twin.gcode.reader.read_program` into a :class:`Plan`."""
    options = options or PlanOptions()
    moves = program.moves
    if not moves:
        raise GcodeError(program.name, 0, "program", "has no moves to run")
    n = len(moves)
    dwell = np.zeros(n + 1)  # dwell before move k (k = n: after the last)
    count = 0
    for item in program.items:
        if isinstance(item, Dwell):
            dwell[count] += item.seconds
        else:
            count += 1
    table = MoveTable(moves)
    feed = np.array([m.feed_m_s for m in moves])
    rapid = np.array([m.rapid for m in moves])
    speed, accel, jerk = _move_limits(table, feed, rapid, options)
    # Tangents at each move's start and end.
    a_start = table.start_tangent_angle()
    a_end = a_start + table.sweep
    t_start = np.stack([libm.cos(a_start), libm.sin(a_start)], axis=1)
    t_end = np.stack([libm.cos(a_end), libm.sin(a_end)], axis=1)
    kind = np.full(n + 1, STOP)
    cap = np.zeros(n + 1)
    ramp_a = np.ones(n + 1)
    ramp_j = np.ones(n + 1)
    if n > 1:
        a, b = np.arange(n - 1), np.arange(1, n)
        cos_turn = np.clip(np.einsum("ij,ij->i", t_end[a], t_start[b]), -1.0, 1.0)
        turn = np.arccos(cos_turn)
        same_curve = np.abs(table.curvature[a] - table.curvature[b]) <= 1e-9 * np.maximum(
            1.0, np.abs(table.curvature[a])
        )
        exact = np.array([m.exact_stop for m in moves[:-1]])
        tolerance = np.array([m.tolerance_m for m in moves[:-1]])
        stop = rapid[a] | rapid[b] | (dwell[b] > 0) | (turn > options.blend_angle_max_rad)
        passing = ~stop & (turn <= 1e-9) & same_curve
        blending = ~stop & ~passing & ~exact
        kind[b[passing]] = PASS
        cap[b[passing]] = np.minimum(speed[a], speed[b])[passing]
        rot = _RAMP_ARC_RAD * (table.is_arc[a].astype(float) + table.is_arc[b])
        room = np.minimum(table.length[a], table.length[b]) * _RAMP_SHARE
        for side in (a, b):
            room = np.where(table.is_arc[side], np.minimum(room, _RAMP_ARC_RAD * table.radius[side]), room)
        jn = dict(
            k_max=np.maximum(np.abs(table.curvature[a]), np.abs(table.curvature[b]))[blending],
            k_sum=(np.abs(table.curvature[a]) + np.abs(table.curvature[b]))[blending],
            spread=(np.abs(t_start[b] - t_end[a]) + rot[:, None])[blending],
            turn=turn[blending],
            room=room[blending],
            tolerance=tolerance[blending],
        )
        blend_speed = _blend_speeds(jn, np.minimum(speed[a], speed[b])[blending], options.limits)
        fast = blend_speed >= options.blend_speed_min_m_s
        idx = b[blending][fast]
        kind[idx] = BLEND
        cap[idx] = blend_speed[fast]
        keep = {key: value[fast] for key, value in jn.items()}
    else:
        keep, idx = {}, np.zeros(0, dtype=int)
    # Look-ahead over the blocks on the middle lengths left by the ramps at their caps.
    ra, rj = _blend_ramp(cap[idx], keep, options.limits) if idx.size else (np.zeros(0), np.zeros(0))
    ramp_a[idx], ramp_j[idx] = ra, rj
    ramp_len = np.zeros(n + 1)
    ramp_len[idx] = 0.5 * cap[idx] * ramp_time(cap[idx], ra, rj)
    middle = table.length - ramp_len[:-1] - ramp_len[1:]
    while True:
        v = _look_ahead(cap, middle, accel, jerk)
        slow = (kind == BLEND) & (v < options.blend_speed_min_m_s)
        if not slow.any():
            break
        kind[slow], cap[slow] = STOP, 0.0  # a blend slowed below the minimum: stop there instead
    blended = np.flatnonzero(kind == BLEND)
    if blended.size:
        sel = np.searchsorted(idx, blended)
        ra, rj = _blend_ramp(v[blended], {key: value[sel] for key, value in keep.items()}, options.limits)
        ramp_a[blended], ramp_j[blended] = np.where(v[blended] > 0, ra, 1.0), np.where(v[blended] > 0, rj, 1.0)
    overlap = (kind == BLEND) & (v > 0)
    ramp_s = np.where(overlap, ramp_time(v, ramp_a, ramp_j), 0.0)
    ramp_len = np.where(overlap, 0.5 * v * ramp_s, 0.0)
    middle = table.length - ramp_len[:-1] - ramp_len[1:]
    peak = peak_speed(v[:-1], v[1:], middle, speed, accel, jerk)
    return _assemble(program, moves, table, options, kind, v, ramp_a, ramp_j, ramp_s, middle, peak, accel, jerk, dwell)


def _look_ahead(cap: np.ndarray, middle: np.ndarray, accel: np.ndarray, jerk: np.ndarray) -> np.ndarray:
    """Junction speeds <= cap such that every move can change between its two (backward, then forward pass)."""
    v = cap.copy()
    n = len(middle)
    for k in range(n - 1, -1, -1):
        v[k] = min(v[k], reach_speed(v[k + 1], middle[k], accel[k], jerk[k]))
    for k in range(n):
        v[k + 1] = min(v[k + 1], reach_speed(v[k], middle[k], accel[k], jerk[k]))
    return v


def _assemble(program, moves, table, options, kind, v, ramp_a, ramp_j, ramp_s, middle, peak, accel, jerk, dwell):
    """Phases of every move and the timeline (starts, overlaps, stops with their pivots)."""
    n = len(moves)
    table_out = np.empty((6, 13 * n))  # rows: move, tau0, u0, v0, a0, jerk; at most 13 phases a move
    duration = np.zeros(n)
    first = np.zeros(n + 1, dtype=int)
    v, ramp_a, ramp_j, ramp_s = v.tolist(), ramp_a.tolist(), ramp_j.tolist(), ramp_s.tolist()
    middle, peak, accel, jerk = middle.tolist(), peak.tolist(), accel.tolist(), jerk.tolist()
    i = 0
    for k in range(n):
        phases = []
        if ramp_s[k] > 0:
            phases += ramp_phases(0.0, v[k], ramp_a[k], ramp_j[k])
        phases += ramp_phases(v[k], peak[k], accel[k], jerk[k])
        cruise = (
            middle[k]
            - float(ramp_distance(v[k], peak[k], accel[k], jerk[k]))
            - float(ramp_distance(peak[k], v[k + 1], accel[k], jerk[k]))
        )
        if cruise > 0 and peak[k] > 0:
            phases.append((cruise / peak[k], 0.0))
        phases += ramp_phases(peak[k], v[k + 1], accel[k], jerk[k])
        if ramp_s[k + 1] > 0:
            phases += ramp_phases(v[k + 1], 0.0, ramp_a[k + 1], ramp_j[k + 1])
        first[k] = i
        t, u, acc = 0.0, 0.0, 0.0
        s = 0.0 if ramp_s[k] > 0 else v[k]  # a pass-through junction: the move starts moving
        for length, j in phases:
            table_out[:, i] = (k, t, u, s, acc, j)
            i += 1
            u += s * length + acc * length**2 / 2 + j * length**3 / 6
            s += acc * length + j * length**2 / 2
            acc += j * length
            t += length
        duration[k] = t
    first[n] = i
    a_start = table.start_tangent_angle()
    alpha_start = np.zeros(n)
    alpha_end = np.zeros(n)
    for k in range(n):
        if k == 0:
            alpha_start[k] = a_start[0]
        else:
            alpha_start[k] = alpha_end[k - 1] + _wrap(a_start[k] - alpha_end[k - 1])
        alpha_end[k] = alpha_start[k] + table.sweep[k]
    t0 = np.zeros(n)
    pivot = np.zeros(n)
    t = dwell[0]
    for k in range(n):
        if k > 0:
            if kind[k] == BLEND and v[k] > 0:
                t -= ramp_s[k]
            elif kind[k] == STOP:
                pivot[k] = options.pivot_s if abs(alpha_start[k] - alpha_end[k - 1]) > 1e-12 else 0.0
                t += dwell[k] + pivot[k]
        t0[k] = t
        t += duration[k]
    total = t + dwell[n] + options.hold_end_s
    phases = table_out[:, :i]
    return Plan(
        program, table, options, t0, duration, first, phases, kind, np.asarray(v), alpha_start, alpha_end, pivot, total
    )


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi
