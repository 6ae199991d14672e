"""Desired contours: a geometric curve p(phi) and a timing law phi(t).

The equations: docs/equations.md, contour and timing law. A path supplies p
and its first three derivatives with respect to phi; a timing law supplies
phi and its first three time derivatives. :func:`reference` combines them into everything the controller
and the task frame need, vectorised over time:

    q_d'  = p_phi phi'
    q_d'' = p_phiphi phi'^2 + p_phi phi''
    alpha = atan2(dy/dphi, dx/dphi)                (defined at rest)
    alpha'  = alpha_phi phi'
    alpha'' = alpha_phiphi phi'^2 + alpha_phi phi''

A new path type is one new class implementing :class:`Contour`. A contour
planned ahead in time (a part program, :mod:`gantry_twin.gcode`) is a
:class:`TimedContour`: its parameter is time (run it with
``TimingLaw(1.0)``, phi = t) and it gives the reference and the contour
error itself, since its tangent at a standstill is not dp/dphi's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from gantry_twin.numerics import libm
from gantry_twin.numerics.jit import kernel
from gantry_twin.settings import quote


class Contour(Protocol):
    """A smooth planar curve parametrised by phi (radians or any unit)."""

    def derivatives(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """p, dp/dphi, d2p/dphi2, d3p/dphi3 at each phi, each of shape (..., 2), metres."""
        ...

    @property
    def period_rad(self) -> float:
        """Phi advance of one lap (2 pi for closed curves)."""
        ...


class TimedContour(Contour, Protocol):
    """A contour parametrised by time that supplies its own reference and contour error.

    ``reference(t_s)`` is the :class:`Reference` at times t_s (phi = t,
    phi' = 1); ``contour_error(q_m, phi_guess)`` returns (eps_c m, phi of
    the closest point) like :func:`contour_error`. :class:`ReferenceStream`
    and :func:`contour_error` use them when a contour has them.
    """

    def reference(self, t_s: np.ndarray) -> Reference: ...

    def contour_error(self, q_m: np.ndarray, phi_guess: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


class ReferenceEnded(Exception):
    """Raised by a live :class:`TimedContour`'s ``reference(t_s)`` when its source has ended (the machine that
    streamed the commands stopped): the run ends there, with the samples before ``t_s``, as a run that reached its
    duration does. ``str()`` says why."""


@dataclass(frozen=True)
class Ellipse:
    """p(phi) = centre + [a sin phi, -b cos phi]: starts at the bottom, moving +x.

    The paper's ellipse (5.2) is ``Ellipse(0.2, 0.1, (0, 0.1))``:
    [0.2 sin phi, -0.1 cos phi + 0.1].
    """

    semi_x_m: float
    semi_y_m: float
    centre_m: tuple[float, float] = (0.0, 0.0)

    @property
    def period_rad(self) -> float:
        return 2.0 * math.pi

    def derivatives(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        phi = np.asarray(phi, dtype=float)
        s, c = libm.sin(phi), libm.cos(phi)
        a, b = self.semi_x_m, self.semi_y_m
        p = np.stack([self.centre_m[0] + a * s, self.centre_m[1] - b * c], axis=-1)
        dp = np.stack([a * c, b * s], axis=-1)
        ddp = np.stack([-a * s, b * c], axis=-1)
        dddp = np.stack([-a * c, -b * s], axis=-1)
        return p, dp, ddp, dddp


def circle(radius_m: float = 0.2, centre_m: tuple[float, float] = (0.0, 0.0)) -> Ellipse:
    """The paper's circle (5.1): radius 0.2 m, centred in the travel."""
    return Ellipse(radius_m, radius_m, centre_m)


def paper_ellipse() -> Ellipse:
    """The paper's ellipse (5.2): [0.2 sin phi, -0.1 cos phi + 0.1]."""
    return Ellipse(0.2, 0.1, (0.0, 0.1))


@dataclass(frozen=True)
class TimingLaw:
    """phi(t) at a constant rate after an optional smooth start.

    rate_rad_s: the final phi' (paper: 2 rad/s circle, 3 rad/s ellipse).
    start: ``on_path`` -- phi = rate t from t = 0, the plant already moving
    (the paper's scenarios); ``rest`` -- phi' ramps from 0 to the rate with a
    quintic smoothstep over ``ramp_s`` seconds (phi''' continuous).
    """

    rate_rad_s: float
    start: Literal["on_path", "rest"] = "on_path"
    ramp_s: float = 0.5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_rad_s) and self.rate_rad_s > 0.0):
            raise ValueError(f"timing.rate_rad_s: must be a finite number > 0 rad/s, got {quote(self.rate_rad_s)}")
        if self.start not in ("on_path", "rest"):
            raise ValueError(f"timing.start: must be 'on_path' or 'rest', got {quote(self.start)}")
        if self.start == "rest" and not (math.isfinite(self.ramp_s) and self.ramp_s > 0.0):
            raise ValueError(f"timing.ramp_s: must be a finite number > 0 s, got {quote(self.ramp_s)}")

    def derivatives(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """phi, phi', phi'', phi''' at each time (rad, rad/s, rad/s^2, rad/s^3)."""
        t = np.asarray(t_s, dtype=float)
        w = self.rate_rad_s
        if self.start == "on_path":
            return w * t, np.full_like(t, w), np.zeros_like(t), np.zeros_like(t)
        tr = self.ramp_s
        tau = np.clip(t / tr, 0.0, 1.0)
        smooth = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
        smooth_d = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / tr
        smooth_dd = (60 * tau - 180 * tau**2 + 120 * tau**3) / tr**2
        integral = tr * (2.5 * tau**4 - 3 * tau**5 + tau**6)
        ramping = t < tr
        phi = np.where(ramping, w * integral, w * (0.5 * tr + (t - tr)))
        phi = np.where(t < 0.0, 0.0, phi)
        return phi, w * smooth, np.where(ramping, w * smooth_d, 0.0), np.where(ramping, w * smooth_dd, 0.0)

    @property
    def settled_s(self) -> float:
        """Time from which phi' equals the rate."""
        return 0.0 if self.start == "on_path" else self.ramp_s


@dataclass(frozen=True)
class Reference:
    """The desired motion sampled at times t (arrays over time, SI units).

    q_d, dq_d, ddq_d: (N, 2) position m, velocity m/s, acceleration m/s^2.
    alpha, dalpha, ddalpha: (N,) tangent angle rad and its derivatives.
    phi, dphi: (N,) path parameter and its rate.
    """

    t_s: np.ndarray
    phi: np.ndarray
    dphi: np.ndarray
    q_d: np.ndarray
    dq_d: np.ndarray
    ddq_d: np.ndarray
    alpha: np.ndarray
    dalpha: np.ndarray
    ddalpha: np.ndarray

    def packed(self) -> np.ndarray:
        """(N, 9) rows [xd, yd, xd', yd', xd'', yd'', alpha, alpha', alpha''] for the loop."""
        return np.column_stack([self.q_d, self.dq_d, self.ddq_d, self.alpha, self.dalpha, self.ddalpha])


def tangent_angle(path: Contour, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """alpha(phi) and its first two phi-derivatives from the curve geometry."""
    _, dp, ddp, dddp = path.derivatives(phi)
    x1, y1 = dp[..., 0], dp[..., 1]
    x2, y2 = ddp[..., 0], ddp[..., 1]
    x3, y3 = dddp[..., 0], dddp[..., 1]
    num = x1 * y2 - y1 * x2
    den = x1 * x1 + y1 * y1
    alpha = libm.atan2(y1, x1)
    alpha_phi = num / den
    alpha_phiphi = ((x1 * y3 - y1 * x3) * den - num * 2.0 * (x1 * x2 + y1 * y2)) / den**2
    return alpha, alpha_phi, alpha_phiphi


def reference(path: Contour, timing: TimingLaw, t_s: np.ndarray) -> Reference:
    """Sample the desired motion at times t_s (vectorised)."""
    return ReferenceStream(path, timing).next(t_s)


class ReferenceStream:
    """:func:`reference` over consecutive pieces of a run's times, for a run held piece by piece.

    The pieces give the same arrays, bit for bit, as one call over all the
    times: every quantity is a function of its own time alone, except alpha,
    which is unwrapped across the pieces (``np.unwrap``'s operations, carried
    on from the last sample of the previous piece).
    """

    def __init__(self, path: Contour, timing: TimingLaw) -> None:
        self.path, self.timing = path, timing
        self._last: tuple[float, float] | None = None  # (raw alpha, its accumulated correction) of the last sample

    def next(self, t_s: np.ndarray) -> Reference:
        """The reference at the times t_s that follow the previous piece's."""
        path = self.path
        own = getattr(path, "reference", None)
        if callable(own):  # a TimedContour: alpha is continuous already
            return own(np.asarray(t_s, dtype=float))
        phi, dphi, ddphi, _ = self.timing.derivatives(t_s)
        p, dp, ddp, _ = path.derivatives(phi)
        alpha, a_phi, a_phiphi = tangent_angle(path, phi)
        dq = dp * dphi[:, None]
        ddq = ddp * (dphi**2)[:, None] + dp * ddphi[:, None]
        # Unwrap so alpha is continuous along the run (the frame only uses sin/cos).
        alpha = self._unwrap(alpha)
        return Reference(
            t_s=np.asarray(t_s, dtype=float),
            phi=phi,
            dphi=dphi,
            q_d=p,
            dq_d=dq,
            ddq_d=ddq,
            alpha=alpha,
            dalpha=a_phi * dphi,
            ddalpha=a_phiphi * dphi**2 + a_phi * ddphi,
        )

    def _unwrap(self, raw: np.ndarray) -> np.ndarray:
        """``np.unwrap(raw)`` continued from the previous piece (the same operations, period 2 pi)."""
        if raw.size == 0:
            return raw.copy()
        if self._last is None:
            accumulated = np.cumsum(_unwrap_corrections(np.diff(raw)))
            out = raw.copy()
            out[1:] = raw[1:] + accumulated
            last = float(accumulated[-1]) if accumulated.size else 0.0
        else:
            corrections = _unwrap_corrections(np.diff(np.concatenate([[self._last[0]], raw])))
            accumulated = np.cumsum(np.concatenate([[self._last[1]], corrections]))[1:]
            out = raw + accumulated
            last = float(accumulated[-1])
        self._last = (float(raw[-1]), last)
        return out


def _unwrap_corrections(dd: np.ndarray) -> np.ndarray:
    """The phase correction np.unwrap adds for each difference dd of successive angles (period 2 pi)."""
    period = 2.0 * math.pi
    high = period / 2
    ddmod = np.mod(dd + high, period) - high
    np.copyto(ddmod, high, where=(ddmod == -high) & (dd > 0))
    correction = ddmod - dd
    np.copyto(correction, 0, where=np.abs(dd) < high)
    return correction


def contour_error(
    path: Contour, q_m: np.ndarray, phi_guess: np.ndarray, iterations: int = 8, tolerance_rad: float = 1e-13
) -> tuple[np.ndarray, np.ndarray]:
    """True contouring error eps_c: distance from q to the whole curve (metres).

    Local Newton search for the closest point, started at the desired phi(t)
    and kept within a quarter lap of it; it stops once no Newton step of any
    sample is larger than ``tolerance_rad`` (two or three steps for um-scale
    errors). Signed like eps_n: positive along the normal
    n = [-sin alpha, cos alpha] (the first row of T). Returns (eps_c, phi of
    the closest point). An :class:`Ellipse` is searched by a compiled kernel
    (:func:`ellipse_contour_error`, the same operations), any other path with
    numpy through its ``derivatives``.
    """
    q = np.ascontiguousarray(q_m, dtype=float)
    guess = np.ascontiguousarray(phi_guess, dtype=float)
    own = getattr(path, "contour_error", None)
    if callable(own):  # a TimedContour
        return own(q, guess)
    if isinstance(path, Ellipse) and q.ndim == 2:
        eps, phi = np.empty(guess.shape[0]), np.empty(guess.shape[0])
        ellipse_contour_error(
            float(path.semi_x_m),
            float(path.semi_y_m),
            float(path.centre_m[0]),
            float(path.centre_m[1]),
            q,
            guess,
            0.25 * path.period_rad,
            int(iterations),
            float(tolerance_rad),
            eps,
            phi,
        )
        return eps, phi
    phi = guess.copy()
    limit = 0.25 * path.period_rad
    for _ in range(iterations):
        p, dp, ddp, _ = path.derivatives(phi)
        r = p - q
        speed2 = np.einsum("...i,...i", dp, dp)
        hess = speed2 + np.einsum("...i,...i", r, ddp)
        step = np.einsum("...i,...i", r, dp) / np.where(hess > 1e-12, hess, speed2)
        phi = np.clip(phi - step, guess - limit, guess + limit)
        if np.all(np.abs(step) <= tolerance_rad):
            break
    p, dp, _, _ = path.derivatives(phi)
    alpha = libm.atan2(dp[..., 1], dp[..., 0])
    normal = np.stack([-libm.sin(alpha), libm.cos(alpha)], axis=-1)
    d = q - p
    distance = np.linalg.norm(d, axis=-1)
    sign = np.where(np.einsum("...i,...i", d, normal) >= 0.0, 1.0, -1.0)
    return sign * distance, phi


@kernel(nrt=False)
def ellipse_contour_error(
    semi_x, semi_y, centre_x, centre_y, q, phi_guess, limit, iterations, tolerance_rad, eps_c, phi
):
    """:func:`contour_error` for the ellipse p = centre + [a sin phi, -b cos phi], samples q (n, 2) m.

    Each Newton iteration updates every sample, and the search stops when
    no sample's step exceeds tolerance_rad, as the vectorised form does, so
    both give the same bits. Writes eps_c (n,) m and phi (n,).
    """
    n = q.shape[0]
    for i in range(n):
        phi[i] = phi_guess[i]
    for _ in range(iterations):
        converged = True
        for i in range(n):
            s, c = math.sin(phi[i]), math.cos(phi[i])
            r0 = (centre_x + semi_x * s) - q[i, 0]
            r1 = (centre_y - semi_y * c) - q[i, 1]
            d0, d1 = semi_x * c, semi_y * s
            speed2 = d0 * d0 + d1 * d1
            hess = speed2 + (r0 * (-semi_x * s) + r1 * (semi_y * c))
            step = (r0 * d0 + r1 * d1) / (hess if hess > 1e-12 else speed2)
            phi[i] = min(max(phi[i] - step, phi_guess[i] - limit), phi_guess[i] + limit)
            converged = converged and abs(step) <= tolerance_rad
        if converged:
            break
    for i in range(n):
        s, c = math.sin(phi[i]), math.cos(phi[i])
        alpha = math.atan2(semi_y * s, semi_x * c)
        e0 = q[i, 0] - (centre_x + semi_x * s)
        e1 = q[i, 1] - (centre_y - semi_y * c)
        distance = math.sqrt(e0 * e0 + e1 * e1)
        eps_c[i] = distance if e0 * -math.sin(alpha) + e1 * math.cos(alpha) >= 0.0 else -distance
