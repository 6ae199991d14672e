"""One-dimensional jerk-limited speed changes along the path (the planner's building block).

A speed change from v0 to v1 with |acceleration| <= A and |jerk| <= J, at
rest in acceleration at both ends, is the classic double-S ramp
(Biagiotti and Melchiorri, Trajectory Planning for Automatic Machines and
Robots, section 3.4): jerk +J for Tj, none for Tc, -J for Tj (signs swapped
when slowing down), with, for dv = |v1 - v0|,

    dv >= A^2 / J:  Tj = A / J,          Tc = dv / A - A / J
    dv <  A^2 / J:  Tj = sqrt(dv / J),   Tc = 0

It takes T = 2 Tj + Tc and covers (v0 + v1) / 2 T (the ramp's speed is
point-symmetric about its middle). The functions take numpy arrays or
floats. Docs: docs/gcode.md.
"""

from __future__ import annotations

import math

import numpy as np


def ramp_time(dv, accel, jerk):
    """T of a speed change by dv >= 0 (s)."""
    dv = np.asarray(dv, dtype=float)
    full = dv >= accel * accel / jerk
    return np.where(full, dv / accel + accel / jerk, 2.0 * np.sqrt(np.maximum(dv, 0.0) / jerk))


def ramp_distance(v0, v1, accel, jerk):
    """Path length of the speed change v0 -> v1 (m)."""
    return 0.5 * (np.asarray(v0) + np.asarray(v1)) * ramp_time(np.abs(np.asarray(v1) - np.asarray(v0)), accel, jerk)


def half_ramp_distance(speed, accel, jerk):
    """Path length covered in the first half (in time) of the ramp 0 -> speed (m)."""
    speed = np.asarray(speed, dtype=float)
    full = speed >= accel * accel / jerk
    tj_short = np.sqrt(np.maximum(speed, 0.0) / jerk)
    short = jerk * tj_short**3 / 6.0
    tj = accel / jerk
    half_tc = 0.5 * np.maximum(speed / accel - tj, 0.0)
    long = jerk * tj**3 / 6.0 + 0.5 * accel * tj * half_tc + 0.5 * accel * half_tc**2
    return np.where(full, long, short)


def ramp_phases(v0: float, v1: float, accel: float, jerk: float) -> list[tuple[float, float]]:
    """The ramp v0 -> v1 as (duration s, jerk m/s^3) phases (none when v0 == v1)."""
    dv = abs(v1 - v0)
    if dv <= 0.0:
        return []
    sign = 1.0 if v1 > v0 else -1.0
    if dv >= accel * accel / jerk:
        tj = accel / jerk
        tc = dv / accel - tj
        phases = [(tj, sign * jerk), (tc, 0.0), (tj, -sign * jerk)]
        return [p for p in phases if p[0] > 0.0]
    tj = math.sqrt(dv / jerk)
    return [(tj, sign * jerk), (tj, -sign * jerk)]


def reach_speed(v: float, length: float, accel: float, jerk: float) -> float:
    """The highest v' >= v a ramp from v reaches within ``length`` (the inverse of :func:`ramp_distance`)."""
    if length <= 0.0:
        return v
    # Short ramp: length = (2 v + dv) sqrt(dv / J); with x = sqrt(dv / J): J x^3 + 2 v x - length = 0.
    p, q = 2.0 * v / jerk, -length / jerk
    root = math.sqrt(q * q / 4.0 + p**3 / 27.0)
    x = math.copysign(abs(-q / 2.0 + root) ** (1 / 3), -q / 2.0 + root)
    x += math.copysign(abs(-q / 2.0 - root) ** (1 / 3), -q / 2.0 - root)
    dv = jerk * x * x
    if dv > accel * accel / jerk:
        # Long ramp: length = (2 v + dv) / 2 (dv / A + A / J), a quadratic in dv.
        a2, b = 1.0 / accel, 2.0 * v / accel + accel / jerk
        c = 2.0 * v * accel / jerk - 2.0 * length
        dv = (-b + math.sqrt(b * b - 4.0 * a2 * c)) / (2.0 * a2)
    return v + max(dv, 0.0)


def peak_speed(v0, v1, length, speed_max, accel, jerk, iterations: int = 60):
    """The highest cruise speed in [max(v0, v1), speed_max] that v0 -> peak -> v1 fits in ``length`` (arrays).

    Bisection on the monotone total ramp length; the answer always fits.
    """
    v0, v1 = np.asarray(v0, dtype=float), np.asarray(v1, dtype=float)
    lo = np.maximum(v0, v1)
    hi = np.maximum(np.asarray(speed_max, dtype=float), lo)

    def needed(peak):
        return ramp_distance(v0, peak, accel, jerk) + ramp_distance(peak, v1, accel, jerk)

    fits = needed(hi) <= length
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        ok = needed(mid) <= length
        lo = np.where(ok, mid, lo)
        hi = np.where(ok, hi, mid)
    return np.where(fits, np.maximum(np.asarray(speed_max, dtype=float), np.maximum(v0, v1)), lo)
