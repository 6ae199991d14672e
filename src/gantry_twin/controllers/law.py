"""The control law DRC, DARC and DIARC share (docs/equations.md, the control laws).

    a_r = q_d'' - L' e - L e'                        reference acceleration
    Phi = [[a_r1, 0, x', 0, Sf(x'), 0, -1, 0],       Cartesian regressor (2 x 8)
           [0, a_r2, 0, y', 0, Sf(y'), 0, -1]]
    u_s = -T Ks T s_c                                robust feedback (eq. 14)
    u   = clip(Phi theta^ - dc^ + u_s)               (eq. 13, 17, 21)

The controllers differ only in where theta^ and dc^ come from. The
per-sample functions are numba kernels (:mod:`gantry_twin.numerics.jit`) writing
into a preallocated :class:`LawWork`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from gantry_twin.controllers.base import REF_ALPHA, REF_DALPHA, REF_DDALPHA, REF_DDQ, REF_DQ, REF_Q
from gantry_twin.numerics.estimation import FRICTION_SLOPE_S_M, FrictionSlope, clip, friction_shape
from gantry_twin.numerics.jit import kernel
from gantry_twin.paths.taskframe import error_gains, sliding_variable
from gantry_twin.plant.model import THETA_NAMES
from gantry_twin.settings import Number, Range, Real, Vector, rule, validated

#: The paper's initial estimates theta0 (section 5), volt units.
THETA0 = (0.1, 0.55, 0.35, 0.5, 0.1, 0.15, 0.0, 0.0)
#: Parameter bounds of eq. (7), section 5.
THETA_MIN = (0.05, 0.45, 0.35, 0.5, 0.05, 0.08, -0.5, -1.0)
THETA_MAX = (0.20, 0.60, 0.55, 0.8, 0.15, 0.25, 0.5, 1.0)


#: theta-shaped settings: eight finite numbers, volt units, named as THETA_NAMES.
Theta = Vector(Real, THETA_NAMES)
#: The task frame's (normal, tangential) components of a gain.
TASK_AXES = ("normal", "tangential")
#: Lambda, 1/s: from 1 (an error decays within a second) to 5000 (lambda Ts = 1: the sliding surface's
#: dynamics still span a sample).
Lambda = Vector(Range(1.0, 5000.0, "1/s"), TASK_AXES)
#: Ks, V/(m/s): from 1 (below, the robust feedback hardly acts) to 1000, below the discrete velocity
#: loop's stability limit Ks Ts / M1 < 2 on the lightest axis (M1 = 0.12 V s^2/m: Ks < 1200).
Ks = Vector(Range(1.0, 1000.0, "V/(m/s)"), TASK_AXES)


@validated("gains")
class ArcGains:
    """Settings shared by the three controllers (paper section 5).

    lambda_1_s: Lambda = diag(lambda_n, lambda_t), 1/s (task frame).
    ks_v_s_m: Ks = diag(k_n, k_t), V/(m/s) (task frame).
    friction_slope_s_m: the 9000 in Sf(v) = (2/pi) atan(9000 v), s/m.
    theta0, theta_min, theta_max: initial estimate and bounds, volt units.
    theta0 may be any number here: DRC fixes theta^ = theta0 anywhere (the
    true parameters, a NaN that the loop must catch); a scenario file also
    requires :meth:`theta0_in_bounds`, the adaptive laws' starting point.
    """

    lambda_1_s: Lambda = (100.0, 30.0)
    ks_v_s_m: Ks = (100.0, 60.0)
    friction_slope_s_m: FrictionSlope = FRICTION_SLOPE_S_M
    theta0: Vector(Number, THETA_NAMES) = THETA0
    theta_min: Theta = THETA_MIN
    theta_max: Theta = THETA_MAX

    def __post_init__(self) -> None:
        if np.any(self.lower > self.upper):
            raise rule("theta_max", "need theta_min <= theta_max element-wise")

    def theta0_in_bounds(self) -> bool:
        """theta_min <= theta0 <= theta_max element-wise (False for a NaN)."""
        th = np.asarray(self.theta0)
        return bool(np.all((self.lower <= th) & (th <= self.upper)))

    @property
    def lam(self) -> np.ndarray:
        """Diagonal of Lambda (2,), 1/s."""
        return np.asarray(self.lambda_1_s, dtype=float)

    @property
    def ks(self) -> np.ndarray:
        """Diagonal of Ks (2,), V/(m/s)."""
        return np.asarray(self.ks_v_s_m, dtype=float)

    @property
    def lower(self) -> np.ndarray:
        """theta_min (8,), volt units."""
        return np.asarray(self.theta_min, dtype=float)

    @property
    def upper(self) -> np.ndarray:
        """theta_max (8,), volt units."""
        return np.asarray(self.theta_max, dtype=float)


class LawWork(NamedTuple):
    """One sample of the shared law, preallocated (SI units, volts).

    t, big_l, big_l_dot: T, L, L' (2 x 2); e, de: tracking errors m, m/s;
    s_c: Cartesian sliding variable, m/s; a_r: reference acceleration m/s^2;
    phi: the regressor (2 x 8); u_v: the clipped command (X, Y), volts.
    """

    t: np.ndarray
    big_l: np.ndarray
    big_l_dot: np.ndarray
    e: np.ndarray
    de: np.ndarray
    s_c: np.ndarray
    a_r: np.ndarray
    phi: np.ndarray
    u_v: np.ndarray


def law_work() -> LawWork:
    """A zeroed :class:`LawWork`."""
    z2 = np.zeros(2)
    return LawWork(
        np.zeros((2, 2)),
        np.zeros((2, 2)),
        np.zeros((2, 2)),
        z2.copy(),
        z2.copy(),
        z2.copy(),
        z2.copy(),
        np.zeros((2, 8)),
        z2.copy(),
    )


@kernel
def regressor(a_r, dq_m_s, friction_slope_s_m, out=None):
    """Cartesian regressor Phi (2 x 8) of the error dynamics (docs/equations.md)."""
    if out is None:
        out = np.empty((2, 8))
    out[:, :] = 0.0
    out[0, 0], out[1, 1] = a_r[0], a_r[1]
    out[0, 2], out[1, 3] = dq_m_s[0], dq_m_s[1]
    out[0, 4] = friction_shape(dq_m_s[0], friction_slope_s_m)
    out[1, 5] = friction_shape(dq_m_s[1], friction_slope_s_m)
    out[0, 6] = -1.0
    out[1, 7] = -1.0
    return out


@kernel(nrt=False)
def arc_law(q_m, dq_m_s, ref, theta, dc_v, lam, ks, friction_slope_s_m, u_max_v, work):
    """u = clip(Phi theta^ - dc^ + u_s) with u_s = -T Ks T s_c (eq. 13-14, 17, 21).

    q_m, dq_m_s: measured position m and velocity m/s (X, Y); ref: one row
    of :meth:`Reference.packed`; theta (8,), dc_v (2,) volts (zeros for a
    controller without dc^); lam, ks: diagonals of Lambda 1/s and Ks V/(m/s).
    Fills ``work`` (s_c, phi, u_v, ...) for the adaptation laws.
    """
    # Unpacked once: each namedtuple field access costs a reference-count update in numba.
    t, big_l, big_l_dot, e, de, s_c, a_r, phi, u_v = work
    for i in range(2):
        e[i] = q_m[i] - ref[REF_Q + i]
        de[i] = dq_m_s[i] - ref[REF_DQ + i]
    error_gains(ref[REF_ALPHA], ref[REF_DALPHA], ref[REF_DDALPHA], lam, t, big_l, big_l_dot)
    sliding_variable(e, de, big_l, s_c)
    for i in range(2):
        ldot_e = big_l_dot[i, 0] * e[0] + big_l_dot[i, 1] * e[1]
        l_de = big_l[i, 0] * de[0] + big_l[i, 1] * de[1]
        a_r[i] = ref[REF_DDQ + i] - ldot_e - l_de
    regressor(a_r, dq_m_s, friction_slope_s_m, phi)
    # Task-frame robust feedback: s = T s_c, then back with T (T = T^-1).
    s_n = ks[0] * (t[0, 0] * s_c[0] + t[0, 1] * s_c[1])
    s_t = ks[1] * (t[1, 0] * s_c[0] + t[1, 1] * s_c[1])
    for i in range(2):
        model = 0.0
        for j in range(8):
            model += phi[i, j] * theta[j]
        u = model - (t[i, 0] * s_n + t[i, 1] * s_t) - dc_v[i]
        u_v[i] = clip(u, -u_max_v[i], u_max_v[i])
