"""The control law DRC, DARC and DIARC share (control-spec sections 5-6).

    a_r = q_d'' - L' e - L e'                        reference acceleration
    Phi = [[a_r1, 0, x', 0, Sf(x'), 0, -1, 0],       Cartesian regressor (2 x 8)
           [0, a_r2, 0, y', 0, Sf(y'), 0, -1]]
    u_s = -T Ks T s_c                                robust feedback (eq. 14)
    u   = clip(Phi theta^ - dc^ + u_s)               (eq. 13, 17, 21)

The controllers differ only in where theta^ and dc^ come from.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gantry_twin.estimation import friction_shape
from gantry_twin.taskframe import error_gains, sliding_variable

#: The paper's initial estimates theta0 (section 5), volt units.
THETA0 = (0.1, 0.55, 0.35, 0.5, 0.1, 0.15, 0.0, 0.0)
#: Parameter bounds of eq. (7), section 5.
THETA_MIN = (0.05, 0.45, 0.35, 0.5, 0.05, 0.08, -0.5, -1.0)
THETA_MAX = (0.20, 0.60, 0.55, 0.8, 0.15, 0.25, 0.5, 1.0)


@dataclass(frozen=True)
class ArcGains:
    """Settings shared by the three controllers (paper section 5).

    lambda_1_s: Lambda = diag(lambda_n, lambda_t), 1/s (task frame).
    ks_v_s_m: Ks = diag(k_n, k_t), V/(m/s) (task frame).
    friction_slope_s_m: the 9000 in Sf(v) = (2/pi) atan(9000 v), s/m.
    theta0, theta_min, theta_max: initial estimate and bounds, volt units.
    """

    lambda_1_s: tuple[float, float] = (100.0, 30.0)
    ks_v_s_m: tuple[float, float] = (100.0, 60.0)
    friction_slope_s_m: float = 9000.0
    theta0: tuple[float, ...] = THETA0
    theta_min: tuple[float, ...] = THETA_MIN
    theta_max: tuple[float, ...] = THETA_MAX
    lam: np.ndarray = field(init=False, repr=False, compare=False)
    ks: np.ndarray = field(init=False, repr=False, compare=False)
    lower: np.ndarray = field(init=False, repr=False, compare=False)
    upper: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "lam", np.asarray(self.lambda_1_s, dtype=float))
        object.__setattr__(self, "ks", np.diag(np.asarray(self.ks_v_s_m, dtype=float)))
        object.__setattr__(self, "lower", np.asarray(self.theta_min, dtype=float))
        object.__setattr__(self, "upper", np.asarray(self.theta_max, dtype=float))


def regressor(a_r: np.ndarray, dq_m_s: np.ndarray, friction_slope_s_m: float) -> np.ndarray:
    """Cartesian regressor Phi (2 x 8) of control-spec section 5."""
    sf = friction_shape(dq_m_s, friction_slope_s_m)
    phi = np.zeros((2, 8))
    phi[0, 0], phi[1, 1] = a_r[0], a_r[1]
    phi[0, 2], phi[1, 3] = dq_m_s[0], dq_m_s[1]
    phi[0, 4], phi[1, 5] = sf[0], sf[1]
    phi[0, 6] = phi[1, 7] = -1.0
    return phi


@dataclass
class LawTerms:
    """One sample of the shared law: what the adaptation laws need next.

    u_v: the clipped command (X, Y), volts; s_c: Cartesian sliding variable,
    m/s; phi: the regressor (2 x 8).
    """

    u_v: np.ndarray
    s_c: np.ndarray
    phi: np.ndarray


def arc_law(
    q_m: np.ndarray,
    dq_m_s: np.ndarray,
    q_d: np.ndarray,
    dq_d: np.ndarray,
    ddq_d: np.ndarray,
    alpha: float,
    dalpha: float,
    ddalpha: float,
    theta: np.ndarray,
    dc_v: np.ndarray | None,
    gains: ArcGains,
    u_max_v: np.ndarray,
) -> LawTerms:
    """u = clip(Phi theta^ - dc^ + u_s) with u_s = -T Ks T s_c (eq. 13-14, 17, 21)."""
    e = q_m - q_d
    de = dq_m_s - dq_d
    t, big_l, big_l_dot = error_gains(alpha, dalpha, ddalpha, gains.lam)
    s_c = sliding_variable(e, de, big_l)
    a_r = ddq_d - big_l_dot @ e - big_l @ de
    phi = regressor(a_r, dq_m_s, gains.friction_slope_s_m)
    u = phi @ theta - t @ (gains.ks @ (t @ s_c))
    if dc_v is not None:
        u = u - dc_v
    return LawTerms(np.clip(u, -u_max_v, u_max_v), s_c, phi)
