"""Splines: G5 (cubic), G5.1 (quadratic) and G5.2 / G5.3 (NURBS) sampled into arcs, as LinuxCNC's canon does.

LinuxCNC's G-code reference (G5, G5.1, G5.2 / G5.3) and its interpreter
(``convert_spline``, ``convert_nurbs``): every spline is a NURBS of control
points (x, y, weight) and order k.

- G5 X Y I J P Q: the cubic from the current point with the control points
  start + (I, J) and end + (P, Q), order 4; I J left out take the last G5's
  (-P, -Q) (a smooth chain).
- G5.1 X Y I J: the quadratic through start + (I, J), order 3.
- G5.2 X Y P [L]: a control point of weight P (the first line also takes
  the current point, of weight 1), order L (3 when L is not over 3); more
  lines of X Y P follow; G5.3 ends the curve and moves along it.

G5 and G5.1 leave the motion mode as it was (a line of X Y after them is
the G1 or G0 before); G5.2 is the motion mode until G5.3, which leaves
none, as LinuxCNC 2.9's interpreter does.

The knots are uniform and clamped, 0 k times, then 1, 2, ... n - k + 1,
then n - k + 2 k times, for n + 1 control points; the curve runs from the
first control point to the last. LinuxCNC's canon (``NURBS_FEED``) samples
the curve at 4 (n + 1) equal steps of the knot parameter, takes the tangent
there by central differences (1e-5 of the parameter), and joins each pair
of samples by a biarc: two arcs meeting tangent, matching the sampled
tangents at both ends (an arc whose chord is along the tangent is a line).
:func:`nurbs_biarcs` does the same, in the program's units and frame. Where
no biarc exists (the tangents parallel, or the construction has no
positive solution) the twin joins the two samples by a line; LinuxCNC
then leaves the step out and starts the next arc where it stands.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from gantry_twin.gcode.arcs import spiral_arcs
from gantry_twin.gcode.geometry import Move

#: Samples per control point (LinuxCNC's NURBS_FEED), the tangent's parameter step, the straight-arc test.
SAMPLES_PER_POINT = 4
#: The most control points of one NURBS and its highest order (bounds LinuxCNC has not: a runaway loop of
#: G5.2 lines, or L in the thousands, would take minutes to sample).
MAX_CONTROL_POINTS = 10_000
MAX_ORDER = 20
#: The farthest a control point may be from the program's zero, m (far beyond any travel; the sampling's
#: arithmetic overflows long before a number the lexer reads).
MAX_CONTROL_M = 1e3
TANGENT_STEP = 1e-5
STRAIGHT = 1e-6


def knots(count: int, order: int) -> np.ndarray:
    """The uniform clamped knot vector of ``count`` control points and ``order`` (degree + 1)."""
    n = count - 1
    return np.array([0 if i < order else (i - order + 1 if i <= n else n - order + 2) for i in range(n + order + 1)],
                    dtype=float)  # fmt: skip


def local_basis(u: np.ndarray, order: int, knot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each u: the first index and the ``order`` basis functions not zero there ((m,) and (m, order)), by
    the triangular Cox-de Boor recursion N_i,k(u) = (u - t_i) / (t_i+k-1 - t_i) N_i,k-1(u)
    + (t_i+k - u) / (t_i+k - t_i+1) N_i+1,k-1(u); the last span is closed, so u at the end gives the last
    control point."""
    u = np.asarray(u, dtype=float)
    count, p = len(knot) - order, order - 1
    s = np.clip(np.searchsorted(knot, u, side="right") - 1, p, count - 1)  # knot[s] <= u < knot[s + 1]
    n = np.zeros((len(u), order))
    left, right = np.zeros((len(u), order)), np.zeros((len(u), order))
    n[:, 0] = 1.0
    for j in range(1, order):
        left[:, j], right[:, j] = u - knot[s + 1 - j], knot[s + j] - u
        saved = np.zeros(len(u))
        for r in range(j):
            temp = n[:, r] / (right[:, r + 1] + left[:, j - r])
            n[:, r] = saved + right[:, r + 1] * temp
            saved = left[:, j - r] * temp
        n[:, j] = saved
    return s - p, n


def basis(u: float, order: int, knot: np.ndarray) -> np.ndarray:
    """All the basis functions N_i,order(u), i = 0 .. len(knot) - order - 1."""
    first, local = local_basis(np.array([u]), order, knot)
    out = np.zeros(len(knot) - order)
    out[first[0] : first[0] + order] = local[0]
    return out


def nurbs_points(u: np.ndarray, points: np.ndarray, weights: np.ndarray, order: int, knot: np.ndarray) -> np.ndarray:
    """The curve's points (m, 2) at knot parameters u: sum N_i w_i P_i / sum N_i w_i."""
    first, local = local_basis(u, order, knot)
    index = first[:, None] + np.arange(order)
    nw = local * weights[index]
    return np.einsum("mk,mkd->md", nw, points[index]) / nw.sum(axis=1)[:, None]


def _unit(v: np.ndarray) -> np.ndarray:
    norm = math.hypot(v[0], v[1])
    return v / norm if norm > 0 else v


def nurbs_samples(points: np.ndarray, weights: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """The 4 (n + 1) + 1 points and unit tangents NURBS_FEED joins: (m, 2) each, program units."""
    knot = knots(len(points), order)
    umax = knot[-1]
    count = SAMPLES_PER_POINT * len(points)
    u = umax * np.arange(count + 1) / count
    out = nurbs_points(u, points, weights, order, knot)
    out[0], out[-1] = points[0], points[-1]
    lo, hi = np.maximum(0.0, u - TANGENT_STEP), np.minimum(umax, u + TANGENT_STEP)
    d = (nurbs_points(hi, points, weights, order, knot) - nurbs_points(lo, points, weights, order, knot)) / (hi - lo)[
        :, None
    ]
    norm = np.hypot(d[:, 0], d[:, 1])
    tangents = np.where(norm[:, None] > 0, d / np.where(norm > 0, norm, 1.0)[:, None], d)
    return out, tangents


Piece = tuple[tuple[float, float], tuple[float, float] | None, int]  # end, centre (None: a line), +1 ccw / -1 cw


def _arc(p0: np.ndarray, p1: np.ndarray, direction: np.ndarray) -> Piece:
    """The arc from p0 to p1 leaving p0 along ``direction`` (a line when it is straight)."""
    x, y = p1 - p0
    dx, dy = direction
    den = 2.0 * (y * dx - x * dy)
    end = (float(p1[0]), float(p1[1]))
    if abs(den) <= STRAIGHT:
        return end, None, 0
    r = -(x * x + y * y) / den
    return end, (float(p0[0] + dy * r), float(p0[1] - dx * r)), 1 if r < 0 else -1


def biarc(p0: np.ndarray, t0: np.ndarray, p4: np.ndarray, t4: np.ndarray) -> list[Piece] | None:
    """Two arcs from p0 (leaving along t0) to p4 (arriving along t4), meeting tangent; None when none exists."""
    t0, t4 = _unit(t0), _unit(t4)
    v = p0 - p4
    c = float(v @ v)
    b = 2.0 * float(v @ (t0 + t4))
    a = 2.0 * (float(t0 @ t4) - 1.0)
    discriminant = b * b - 4.0 * a * c
    if discriminant < 0.0 or abs(a) < 1e-15:
        return None
    root = math.sqrt(discriminant)
    beta1, beta2 = (-b - root) / (2.0 * a), (-b + root) / (2.0 * a)
    if beta1 > 0.0 and beta2 > 0.0:
        return None
    beta = max(beta1, beta2)
    if not beta > 0.0:
        return None
    p1, p3 = p0 + beta * t0, p4 - beta * t4
    p2 = 0.5 * (p1 + p3)
    return [_arc(p0, p2, t0), _arc(p2, p4, _unit(p3 - p2))]


def nurbs_biarcs(points: np.ndarray, weights: np.ndarray, order: int) -> list[Piece]:
    """The pieces (end, centre or None, rotation) that follow the NURBS from its first control point, in order."""
    samples, tangents = nurbs_samples(points, weights, order)
    pieces: list[Piece] = []
    for k in range(len(samples) - 1):
        pair = biarc(samples[k], tangents[k], samples[k + 1], tangents[k + 1])
        pieces += pair if pair is not None else [((float(samples[k + 1][0]), float(samples[k + 1][1])), None, 0)]
    return pieces


class SplineMoves:
    """The spline half of :class:`~gantry_twin.gcode.machine.Machine`: G5, G5.1 and G5.2 / G5.3 blocks to arcs."""

    nurbs: list[tuple[float, float, float]]  # G5.2's control points so far: program x, y (program units), weight
    nurbs_order: int
    spline_ij: tuple[float, float]  # the last G5's (-P, -Q): I J of a G5 without them
    position: tuple[float, float]
    scale_m: float
    motion: int | str | None
    compensation: tuple | None
    error: Callable[[str, str], Exception]
    to_program: Callable[[float, float], tuple[float, float]]
    to_machine: Callable[[float, float], tuple[float, float]]
    target: Callable[[dict[str, float]], tuple[float, float]]
    feed_common: Callable[[dict[str, float], int], dict]
    timed: Callable[[list[Move], dict[str, float]], list[Move]]
    emit: Callable[[Move], None]

    def spline(self, words: dict[str, float], number: int) -> None:
        """A G5 / G5.1 block (a curve from the current point) or a G5.2 control point."""
        if self.compensation is not None:
            raise self.error(str(self.motion), "a spline cannot be cut with cutter radius compensation on (G40 first)")
        if "X" in words and "Y" not in words or "Y" in words and "X" not in words:
            if self.motion == "G5.2":
                raise self.error("X" if "X" in words else "Y", "a G5.2 control point needs both X and Y")
        if self.motion == "G5.2":
            self.control_point(words)
            return
        s = self.scale_m
        x0, y0 = (v / s for v in self.to_program(*self.position))
        x3, y3 = (v / s for v in self.to_program(*self.target(words)))
        if self.motion == "G5.1":
            if "I" not in words or "J" not in words:
                raise self.error("G5.1", "needs both I and J (the control point, from the start)")
            points = [(x0, y0), (x0 + words["I"], y0 + words["J"]), (x3, y3)]
        else:
            if ("I" in words) != ("J" in words):
                raise self.error("I" if "I" in words else "J", "G5 needs both I and J, or neither")
            if "P" not in words or "Q" not in words:
                raise self.error("G5", "needs both P and Q (the second control point, from the end)")
            i, j = (words["I"], words["J"]) if "I" in words else self.spline_ij
            points = [(x0, y0), (x0 + i, y0 + j), (x3 + words["P"], y3 + words["Q"]), (x3, y3)]
            self.spline_ij = (-words["P"], -words["Q"])
        self.curve(np.array(points), np.ones(len(points)), len(points), words, number)

    def control_point(self, words: dict[str, float]) -> None:
        """G5.2: the first block takes the current point (weight 1, or P on a block without X Y) and sets the
        order (L over 3, else 3); every block with X Y adds a control point of weight P > 0."""
        s = self.scale_m
        if not self.nurbs:
            x0, y0 = (v / s for v in self.to_program(*self.position))
            weight = words["P"] if "X" not in words and words.get("P", 0.0) > 0.0 else 1.0
            self.nurbs = [(x0, y0, weight)]
            self.nurbs_order = 3
        if "L" in words:
            if words["L"] != int(words["L"]) or not 1 <= words["L"] <= MAX_ORDER:
                raise self.error("L", f"a NURBS order is a whole number 1 to {MAX_ORDER} (over 3 sets it; 3 is the "
                                 "least)")  # fmt: skip
            self.nurbs_order = max(3, int(words["L"])) if words["L"] > 3 else self.nurbs_order
        if "X" in words:
            if words.get("P", 0.0) <= 0.0:
                raise self.error("P", "every G5.2 control point needs a weight P > 0")
            if len(self.nurbs) >= MAX_CONTROL_POINTS:
                raise self.error("G5.2", f"more than {MAX_CONTROL_POINTS} control points in one NURBS (G5.3 ends one)")
            x, y = (v / s for v in self.to_program(*self.target(words)))
            self.nurbs.append((x, y, words["P"]))

    def nurbs_end(self, words: dict[str, float], number: int) -> None:
        """G5.3: the NURBS of the control points G5.2 gave, moved along."""
        if self.motion != "G5.2":
            raise self.error("G5.3", "ends a NURBS: G5.2 first")
        if len(self.nurbs) < self.nurbs_order:
            raise self.error("G5.3", f"a NURBS of order {self.nurbs_order} needs at least {self.nurbs_order} "
                             f"control points, got {len(self.nurbs)}")  # fmt: skip
        control = np.array(self.nurbs)
        self.nurbs, self.motion = [], None
        self.curve(control[:, :2], control[:, 2], self.nurbs_order, words, number)

    def curve(self, points: np.ndarray, weights: np.ndarray, order: int, words: dict[str, float], number: int) -> None:
        """Move along the NURBS (program units and frame) by :func:`nurbs_biarcs`'s pieces, the last one the
        block's end; the feed is the block's (G93: the whole curve in 60 / F s)."""
        s = self.scale_m
        far = float(np.abs(points).max()) * s
        if not far <= MAX_CONTROL_M:  # the curve stays in its points' hull: one a kilometre away cannot be cut
            raise self.error(str(self.motion or "G5.3"), f"a control point {far * 1e3:.6g} mm from the program's "
                             f"zero, more than {MAX_CONTROL_M * 1e3:g} mm")  # fmt: skip
        common = self.feed_common(words, number)
        moves: list[Move] = []
        position = self.position
        for end_p, centre_p, rotation in nurbs_biarcs(points, weights, order):
            end = self.to_machine(end_p[0] * s, end_p[1] * s)
            if centre_p is None:
                if end != position:
                    moves.append(Move("line", position, end, **common, piece=True))
            else:
                centre = self.to_machine(centre_p[0] * s, centre_p[1] * s)
                a0 = math.atan2(position[1] - centre[1], position[0] - centre[0])
                a1 = math.atan2(end[1] - centre[1], end[0] - centre[0])
                sweep = math.fmod(rotation * (a1 - a0), 2.0 * math.pi)
                sweep += 2.0 * math.pi if sweep < 0.0 else 0.0
                if sweep > 0.0:
                    moves += [dataclasses.replace(m, piece=True)
                              for m in spiral_arcs(position, end, centre, rotation * sweep, common)]  # fmt: skip
            position = end
        if not moves:
            return
        moves[-1] = dataclasses.replace(moves[-1], end_m=position, piece=False)
        for move in self.timed(moves, words):
            self.emit(move)
        self.position = position
