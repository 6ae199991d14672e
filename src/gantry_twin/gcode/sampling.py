"""A planned program, sampled at any times: the reference the loop runs and the contour it is measured against.

:class:`Plan` (made by :func:`gantry_twin.gcode.planner.plan_program`) holds
each move's phases of constant jerk and the timeline. At a time t the
latest move started runs; during a blend the move before it still runs its
ramp out, and the two motions' displacements add (the module docstring of
:mod:`gantry_twin.gcode.planner`). It is also a :class:`~gantry_twin.paths.contours.Contour`
whose parameter is time (phi = t, phi' = 1): ``reference`` gives the loop's
:class:`~gantry_twin.paths.contours.Reference` directly and ``contour_error`` the
distance to the planned path, which is what
:class:`~gantry_twin.paths.contours.ReferenceStream` and
:func:`~gantry_twin.paths.contours.contour_error` use for such a contour.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from gantry_twin.gcode.geometry import MoveTable
from gantry_twin.numerics import libm
from gantry_twin.paths.contours import Reference


@dataclass(frozen=True)
class Samples:
    """The reference at times t: position, velocity, acceleration, jerk (n, 2) SI; alpha and its rates; the block."""

    t_s: np.ndarray
    q_m: np.ndarray
    v_m_s: np.ndarray
    a_m_s2: np.ndarray
    j_m_s3: np.ndarray
    alpha_rad: np.ndarray
    dalpha_rad_s: np.ndarray
    ddalpha_rad_s2: np.ndarray
    move: np.ndarray  # index of the latest move started (0 before the first)

    def reference(self) -> Reference:
        """These samples as the loop's :class:`~gantry_twin.paths.contours.Reference` (phi = t, phi' = 1)."""
        return Reference(
            t_s=self.t_s, phi=self.t_s.copy(), dphi=np.ones_like(self.t_s), q_d=self.q_m, dq_d=self.v_m_s,
            ddq_d=self.a_m_s2, alpha=self.alpha_rad, dalpha=self.dalpha_rad_s, ddalpha=self.ddalpha_rad_s2,
        )  # fmt: skip


@runtime_checkable
class ProgramPath(Protocol):
    """A part program's path in time (phi = t): the twin's own :class:`Plan`, or a CNC's recorded commands
    (:class:`gantry_twin.cnc.reference.CncPath`). The loop runs it as a
    :class:`~gantry_twin.paths.contours.TimedContour`; the part error, the part figure and the summary read the
    programmed moves and when each ran: ``program`` (its :class:`~gantry_twin.gcode.program.Program`), ``moves``
    and ``table`` (:class:`MoveTable`), ``rapid`` (moves the part error leaves out), ``t0_s`` / ``end_s`` (when each
    move starts and ends), ``kind`` (each junction: STOP, PASS, BLEND of :mod:`gantry_twin.gcode.planner`),
    ``alpha_start`` / ``alpha_end`` (each move's tangent angles), ``duration_s``, ``sample(t)`` (with ``move``:
    the move run at t) and ``rapid_spans()``."""

    program: object
    moves: list
    table: MoveTable
    rapid: np.ndarray
    t0_s: np.ndarray
    end_s: np.ndarray
    kind: np.ndarray
    alpha_start: np.ndarray
    alpha_end: np.ndarray
    duration_s: float

    def sample(self, t_s: np.ndarray) -> Samples: ...

    def rapid_spans(self) -> list[tuple[float, float]]: ...


class Plan:
    """A program planned: phases per move and their start times. Build with ``plan_program``."""

    def __init__(
        self, program, table, options, t0, duration, first, phases, kind, speed, alpha_start, alpha_end, pivot, total
    ):
        self.program, self.table, self.options = program, table, options
        self.moves = program.moves
        self.t0_s, self.duration_move_s, self.first = t0, duration, first
        self.kind, self.junction_speed_m_s = kind, speed
        self.alpha_start, self.alpha_end, self.pivot_s = alpha_start, alpha_end, pivot
        self.duration_s = float(total)
        seg, self._tau0, self._u0, self._v0, self._a0, self._j = phases
        self._seg = seg.astype(int)
        self._key = self._seg + self._tau0 / duration[self._seg]
        self.end_s = t0 + duration
        #: (moves,) True for a rapid (G0) move: positioning, not part of the part.
        self.rapid = np.array([m.rapid for m in self.moves], dtype=bool)

    def rapid_spans(self) -> list[tuple[float, float]]:
        """(start, end) s of each rapid (G0) move, in order."""
        return [(float(self.t0_s[k]), float(self.end_s[k])) for k in np.flatnonzero(self.rapid)]

    # ------------------------------------------------------------------ Contour protocol (phi = t)
    @property
    def period_rad(self) -> float:
        return self.duration_s

    def derivatives(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """q_d, q_d', q_d'', q_d''' at times phi (the parameter is time)."""
        flat = np.asarray(phi, dtype=float)
        s = self.sample(flat.reshape(-1))
        shape = (*flat.shape, 2)
        return s.q_m.reshape(shape), s.v_m_s.reshape(shape), s.a_m_s2.reshape(shape), s.j_m_s3.reshape(shape)

    def reference(self, t_s: np.ndarray) -> Reference:
        """The loop's reference at times t_s (phi = t)."""
        return self.sample(t_s).reference()

    def contour_error(self, q_m: np.ndarray, phi_guess: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """eps_c against the planned path (:func:`timed_contour_error`, its search). Returns (eps_c m, time s of the
        closest point)."""
        return timed_contour_error(self.sample, self.duration_s, q_m, phi_guess)

    # ------------------------------------------------------------------ sampling
    def _profile(self, k: np.ndarray, tau: np.ndarray):
        """u, u', u'', u''' of move k[i] at local time tau[i] (clamped: at rest before and after)."""
        dur = self.duration_move_s[k]
        tau = np.clip(tau, 0.0, dur)
        idx = np.searchsorted(self._key, k + tau / dur, side="right") - 1
        idx = np.clip(idx, self.first[k], self.first[k + 1] - 1)
        dt = tau - self._tau0[idx]
        j, a0, v0 = self._j[idx], self._a0[idx], self._v0[idx]
        u = self._u0[idx] + v0 * dt + a0 * dt**2 / 2 + j * dt**3 / 6
        du = v0 + a0 * dt + j * dt**2 / 2
        ddu = a0 + j * dt
        done = tau >= dur
        length = self.table.length[k]
        u = np.where(done, length, np.clip(u, 0.0, length))
        return u, np.where(done, 0.0, du), np.where(done, 0.0, ddu), np.where(done, 0.0, j)

    def sample(self, t_s: np.ndarray) -> Samples:
        """The reference at times t_s (vectorised)."""
        t = np.asarray(t_s, dtype=float).reshape(-1)
        table: MoveTable = self.table
        n = table.count
        k = np.clip(np.searchsorted(self.t0_s, t, side="right") - 1, 0, n - 1)
        u, du, ddu, dddu = self._profile(k, t - self.t0_s[k])
        q, v, a, j = table.kinematics(k, u, du, ddu, dddu)
        c = table.curvature[k]
        alpha = self.alpha_start[k] + c * u
        dalpha, ddalpha = c * du, c * ddu
        prev = k - 1
        blend = (prev >= 0) & (t < self.end_s[np.maximum(prev, 0)])
        if blend.any():
            kp = prev[blend]
            up, dup, ddup, dddup = self._profile(kp, t[blend] - self.t0_s[kp])
            qp, vp, ap, jp = table.kinematics(kp, up, dup, ddup, dddup)
            q[blend] += qp - table.end[kp]
            v[blend] += vp
            a[blend] += ap
            j[blend] += jp
            vb, ab, jb = v[blend], a[blend], j[blend]
            speed2 = np.einsum("ij,ij->i", vb, vb)
            cross_a = vb[:, 0] * ab[:, 1] - vb[:, 1] * ab[:, 0]
            cross_j = vb[:, 0] * jb[:, 1] - vb[:, 1] * jb[:, 0]
            raw = libm.atan2(vb[:, 1], vb[:, 0])
            ref = self.alpha_end[kp]
            alpha[blend] = ref + np.mod(raw - ref + np.pi, 2 * np.pi) - np.pi
            dalpha[blend] = cross_a / speed2
            ddalpha[blend] = (cross_j * speed2 - 2.0 * cross_a * np.einsum("ij,ij->i", vb, ab)) / speed2**2
        # A stop's pivot: standing at the corner while alpha turns to the next move's direction.
        nxt = np.minimum(k + 1, n - 1)
        pivot = self.pivot_s[nxt]
        turning = (k + 1 < n) & (pivot > 0) & (t >= self.t0_s[nxt] - pivot) & (t < self.t0_s[nxt])
        if turning.any():
            kk = k[turning]
            x = (t[turning] - (self.t0_s[kk + 1] - pivot[turning])) / pivot[turning]
            turn = self.alpha_start[kk + 1] - self.alpha_end[kk]
            tp = pivot[turning]
            alpha[turning] = self.alpha_end[kk] + turn * (10 * x**3 - 15 * x**4 + 6 * x**5)
            dalpha[turning] = turn * (30 * x**2 - 60 * x**3 + 30 * x**4) / tp
            ddalpha[turning] = turn * (60 * x - 180 * x**2 + 120 * x**3) / tp**2
        return Samples(t, q, v, a, j, alpha, dalpha, ddalpha, k)


def timed_contour_error(
    sample,
    duration_s: float,
    q_m: np.ndarray,
    phi_guess: np.ndarray,
    window_s: float = 0.02,
    coarse_s: float = 2e-3,
    fine_s: float = 2e-4,
) -> tuple[np.ndarray, np.ndarray]:
    """eps_c against a path sampled in time (``sample(t)`` gives :class:`Samples`; t in [0, ``duration_s``]): the
    distance to its nearest chord, signed along the normal [-sin alpha, cos alpha] there. The path is searched every
    ``coarse_s`` within ``window_s`` of the desired time, then every ``fine_s`` about the nearest coarse chord.
    Returns (eps_c m, time s of the closest point)."""  # fmt: skip
    q = np.asarray(q_m, dtype=float).reshape(-1, 2)
    guess = np.asarray(phi_guess, dtype=float).reshape(-1)
    centre = _nearest_chord(sample, duration_s, q, guess, round(window_s / coarse_s), coarse_s)[2]
    dist, nearest, t_best = _nearest_chord(sample, duration_s, q, centre, round(coarse_s / fine_s), fine_s)
    alpha = sample(t_best).alpha_rad
    d = q - nearest
    sign = np.where(d[:, 0] * -libm.sin(alpha) + d[:, 1] * libm.cos(alpha) >= 0.0, 1.0, -1.0)
    return sign * dist, t_best


def _nearest_chord(sample, duration_s: float, q: np.ndarray, centre: np.ndarray, half: int, step_s: float):
    """Distance, point and time of the nearest point of the chords between path samples centre + i step."""
    offsets = np.arange(-half, half + 1) * step_s
    times = np.clip(centre[:, None] + offsets[None, :], 0.0, duration_s)
    points = sample(times.reshape(-1)).q_m.reshape(len(q), len(offsets), 2)
    a, chord = points[:, :-1], np.diff(points, axis=1)
    length2 = np.einsum("nkj,nkj->nk", chord, chord)
    w = np.clip(np.einsum("nkj,nkj->nk", q[:, None] - a, chord) / np.where(length2 > 0, length2, 1.0), 0, 1)
    nearest = a + w[..., None] * chord
    dist = np.linalg.norm(q[:, None] - nearest, axis=2)
    best = np.argmin(dist, axis=1)
    rows = np.arange(len(q))
    t_best = times[rows, best] + w[rows, best] * (times[rows, best + 1] - times[rows, best])
    return dist[rows, best], nearest[rows, best], t_best
