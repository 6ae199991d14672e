"""The programmed geometry of a part program: straight lines and circular arcs in the XY plane.

A :class:`Move` is one block's motion in machine coordinates (metres, origin
at the centre of the travel), parametrised by its arc length u in [0, L]:
a line p(u) = start + u t, an arc p(u) = centre + r [cos(theta0 + sign u / r),
sin(theta0 + sign u / r)]. The reader (:mod:`gantry_twin.gcode.reader`)
makes them, the planner (:mod:`gantry_twin.gcode.planner`) moves along them
and the part error (:mod:`gantry_twin.gcode.part_error`) measures against
them. Docs: docs/gcode.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from gantry_twin.numerics import libm


@dataclass(frozen=True, slots=True)
class Move:
    """One block's motion: a line (``centre_m`` None) or an arc of ``sweep_rad`` (+ counter-clockwise).

    feed_m_s: the programmed path speed (inf for a rapid, planned with the
    rapid limits). exact_stop: G61 in force at this block's end (the machine
    stops at the junction that follows); tolerance_m: G64 P in force (inf: no
    P given). line: the source line, for messages and the per-block error.
    piece: the block goes on in the next move (a spline's arcs, an arc whose
    end is off its circle): this move's end is not the block's end.
    """

    kind: Literal["line", "arc"]
    start_m: tuple[float, float]
    end_m: tuple[float, float]
    feed_m_s: float
    rapid: bool
    line: int
    exact_stop: bool = False
    tolerance_m: float = math.inf
    centre_m: tuple[float, float] | None = None
    sweep_rad: float = 0.0
    piece: bool = False

    @property
    def radius_m(self) -> float:
        """The arc's radius (inf for a line)."""
        if self.centre_m is None:
            return math.inf
        return math.hypot(self.start_m[0] - self.centre_m[0], self.start_m[1] - self.centre_m[1])

    @property
    def length_m(self) -> float:
        if self.centre_m is None:
            return math.hypot(self.end_m[0] - self.start_m[0], self.end_m[1] - self.start_m[1])
        return self.radius_m * abs(self.sweep_rad)

    @property
    def curvature_1_m(self) -> float:
        """Signed curvature (+ turning left, counter-clockwise), 1/m."""
        if self.centre_m is None:
            return 0.0
        return math.copysign(1.0 / self.radius_m, self.sweep_rad)

    @property
    def start_angle_rad(self) -> float:
        """The angle of the start point seen from the arc's centre."""
        assert self.centre_m is not None
        return math.atan2(self.start_m[1] - self.centre_m[1], self.start_m[0] - self.centre_m[0])

    def tangent_angle(self, u_m: float) -> float:
        """The direction of motion at arc length u, rad (not wrapped)."""
        if self.centre_m is None:
            return math.atan2(self.end_m[1] - self.start_m[1], self.end_m[0] - self.start_m[0])
        sign = 1.0 if self.sweep_rad > 0 else -1.0
        return self.start_angle_rad + sign * (u_m / self.radius_m + 0.5 * math.pi)

    @property
    def arc_end_m(self) -> np.ndarray:
        """Where the arc ends on its circle (the programmed end within the reader's tolerance)."""
        if self.centre_m is None:
            return np.asarray(self.end_m)
        angle = self.start_angle_rad + self.sweep_rad
        return np.asarray(self.centre_m) + self.radius_m * np.array([math.cos(angle), math.sin(angle)])


@dataclass(frozen=True, slots=True)
class Dwell:
    """G4 P: stand still for ``seconds`` (s) at the current point."""

    seconds: float
    line: int


def bounding_box(moves: list[Move]) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corners (2,) of every point of the moves (arcs by their extreme points), m."""
    lo = np.full(2, math.inf)
    hi = np.full(2, -math.inf)
    for move in moves:
        for point in (move.start_m, move.end_m):
            lo, hi = np.minimum(lo, point), np.maximum(hi, point)
        if move.centre_m is not None:
            sweep = abs(move.sweep_rad)
            sign = 1.0 if move.sweep_rad > 0 else -1.0
            start = move.start_angle_rad
            for quadrant in range(4):
                angle = quadrant * 0.5 * math.pi
                if np.mod(sign * (angle - start), 2.0 * math.pi) <= sweep:
                    point = np.asarray(move.centre_m) + move.radius_m * np.array([math.cos(angle), math.sin(angle)])
                    lo, hi = np.minimum(lo, point), np.maximum(hi, point)
    return lo, hi


class MoveTable:
    """The moves as arrays, for vectorised evaluation over many samples and many moves.

    Per move k: is_arc, start, unit direction (lines), centre, radius,
    start angle theta0 seen from the centre, turning sign (+1 ccw), signed
    curvature, length.
    """

    def __init__(self, moves: list[Move]) -> None:
        n = len(moves)
        self.count = n
        self.is_arc = np.array([m.centre_m is not None for m in moves], dtype=bool)
        self.start = np.array([m.start_m for m in moves], dtype=float).reshape(n, 2)
        self.end = np.array([m.end_m for m in moves], dtype=float).reshape(n, 2)
        self.length = np.array([m.length_m for m in moves], dtype=float)
        self.centre = np.array([m.centre_m if m.centre_m is not None else (0.0, 0.0) for m in moves]).reshape(n, 2)
        self.radius = np.array([m.radius_m for m in moves], dtype=float)
        self.sweep = np.array([m.sweep_rad for m in moves], dtype=float)
        self.sign = np.where(self.sweep < 0.0, -1.0, 1.0)
        self.curvature = np.where(self.is_arc, self.sign / np.where(self.is_arc, self.radius, 1.0), 0.0)
        rel = self.start - self.centre
        self.theta0 = np.where(self.is_arc, libm.atan2(rel[:, 1], rel[:, 0]), 0.0)
        chord = self.end - self.start
        safe = np.where(self.length > 0, self.length, 1.0)
        self.direction = np.where(self.is_arc[:, None], 0.0, chord / safe[:, None])

    def start_tangent_angle(self) -> np.ndarray:
        """The direction of motion at each move's start, rad in (-pi, pi]."""
        line = libm.atan2(self.direction[:, 1], self.direction[:, 0])
        arc = self.theta0 + self.sign * 0.5 * np.pi
        return np.where(self.is_arc, np.angle(np.exp(1j * arc)), line)

    def kinematics(
        self, k: np.ndarray, u: np.ndarray, du: np.ndarray, ddu: np.ndarray, dddu: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """p, v, a, j (each (n, 2)) of sample i moving along move k[i] at arc length u[i] and its rates.

        Line: p = start + u d. Arc of signed curvature c, tangent t, normal n:
        v = u' t, a = u'' t + c u'^2 n, j = (u''' - c^2 u'^3) t + 3 c u' u'' n.
        """
        arc = self.is_arc[k]
        sign = self.sign[k]
        r = np.where(arc, self.radius[k], 1.0)
        c = self.curvature[k]
        theta = self.theta0[k] + sign * u / r
        cos, sin = libm.cos(theta), libm.sin(theta)
        tangent = np.where(arc[:, None], sign[:, None] * np.stack([-sin, cos], axis=-1), self.direction[k])
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=-1)
        p_arc = self.centre[k] + r[:, None] * np.stack([cos, sin], axis=-1)
        p = np.where(arc[:, None], p_arc, self.start[k] + u[:, None] * self.direction[k])
        v = du[:, None] * tangent
        a = ddu[:, None] * tangent + (c * du * du)[:, None] * normal
        j = (dddu - c * c * du**3)[:, None] * tangent + (3.0 * c * du * ddu)[:, None] * normal
        return p, v, a, j

    def nearest(self, k: np.ndarray, q: np.ndarray) -> np.ndarray:
        """The point of move k[i] (its line segment or arc) nearest to q[i] (n, 2), m."""
        start, end = self.start[k], self.end[k]
        chord = end - start
        length2 = np.einsum("ij,ij->i", chord, chord)
        w = np.clip(np.einsum("ij,ij->i", q - start, chord) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
        line = start + w[:, None] * chord
        rel = q - self.centre[k]
        sweep = np.abs(self.sweep[k])
        angle = np.mod(self.sign[k] * (libm.atan2(rel[:, 1], rel[:, 0]) - self.theta0[k]), 2.0 * np.pi)
        on_arc = (angle <= sweep) | (sweep >= 2.0 * np.pi - 1e-12)
        r = np.linalg.norm(rel, axis=1)
        radial = np.where(r > 0, r, 1.0)
        radius = np.where(self.is_arc[k], self.radius[k], 0.0)  # a line's inf radius is not used
        on_circle = self.centre[k] + (radius / radial)[:, None] * np.where(
            (r > 0)[:, None], rel, start - self.centre[k]
        )
        nearer_start = np.linalg.norm(q - start, axis=1) <= np.linalg.norm(q - end, axis=1)
        ends = np.where(nearer_start[:, None], start, end)
        arc = np.where(on_arc[:, None], on_circle, ends)
        return np.where(self.is_arc[k][:, None], arc, line)

    def polyline(self, k: int, step_rad: float = 0.02) -> np.ndarray:
        """Points (m, 2) along move k, for drawing: a line's two ends, an arc every ``step_rad``."""
        if not self.is_arc[k]:
            return np.array([self.start[k], self.end[k]])
        n = max(2, int(np.ceil(abs(self.sweep[k]) / step_rad)) + 1)
        theta = self.theta0[k] + np.linspace(0.0, self.sweep[k], n)
        return self.centre[k] + self.radius[k] * np.column_stack([libm.cos(theta), libm.sin(theta)])

    def distance(self, k: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Exact distance of q[i] (n, 2) to move k[i] (its line segment or arc), m."""
        start, end = self.start[k], self.end[k]
        chord = end - start
        length2 = np.einsum("ij,ij->i", chord, chord)
        w = np.clip(np.einsum("ij,ij->i", q - start, chord) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
        line = np.linalg.norm(q - (start + w[:, None] * chord), axis=1)
        rel = q - self.centre[k]
        sweep = np.abs(self.sweep[k])
        angle = np.mod(self.sign[k] * (libm.atan2(rel[:, 1], rel[:, 0]) - self.theta0[k]), 2.0 * np.pi)
        on_arc = (angle <= sweep) | (sweep >= 2.0 * np.pi - 1e-12)
        radial = np.abs(np.linalg.norm(rel, axis=1) - self.radius[k])
        ends = np.minimum(np.linalg.norm(q - start, axis=1), np.linalg.norm(q - end, axis=1))
        arc = np.where(on_arc, radial, ends)
        return np.where(self.is_arc[k], arc, line)
