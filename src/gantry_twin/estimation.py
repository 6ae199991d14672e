"""DIARC's indirect estimator and the projections (paper eq. 8-9, 16, 25-28).

Control-spec section 7:

* Each axis is filtered by Hf(s) = wn^2 / (s^2 + 2 z wn s + wn^2). The filters
  are discretised exactly for how each input behaves between samples: the
  position moves continuously, so it is treated as piecewise linear
  (first-order hold); the input u, Sf(q') and the constant are held
  (zero-order hold). A zero-order hold on the position would turn each
  sample's jump into a saw-tooth in x_f''.
* Least squares with covariance limiting (eq. 27-28), rho_M capping only the
  growth from forgetting.
* The discrete projection in the Gamma^-1 metric (the discrete form of
  eq. 16) and the element-wise projection for a diagonal gain (eq. 9).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm


@dataclass(frozen=True)
class FilterDiscretisation:
    """Exact one-sample update of the state z = [w_f, w_f'] of Hf(s).

    phi: (2, 2) state transition over Ts.
    hold: (2,) response to an input held at w over the sample (ZOH).
    ramp: (2,) response to an input rising at 1 unit/s over the sample
    (added to ``hold`` for a first-order hold).
    wn_rad_s, zeta: the filter.
    """

    phi: np.ndarray
    hold: np.ndarray
    ramp: np.ndarray
    wn_rad_s: float
    zeta: float


def discretise_filter(wn_rad_s: float, zeta: float, sample_period_s: float) -> FilterDiscretisation:
    """Matrix exponential of the filter augmented with the input and its slope."""
    a = np.array([[0.0, 1.0], [-(wn_rad_s**2), -2.0 * zeta * wn_rad_s]])
    b = np.array([0.0, wn_rad_s**2])
    aug = np.zeros((4, 4))
    aug[:2, :2] = a
    aug[:2, 2] = b
    aug[2, 3] = 1.0  # the input w grows at its slope, which is held
    e = expm(aug * sample_period_s)
    return FilterDiscretisation(e[:2, :2].copy(), e[:2, 2].copy(), e[:2, 3].copy(), wn_rad_s, zeta)


def filter_step(z: np.ndarray, disc: FilterDiscretisation, w_start: float, slope: float) -> None:
    """Advance one filter state in place over one sample.

    The input is w_start at the start of the sample and grows at ``slope``
    (units/s) through it; slope = 0 is a zero-order hold.
    """
    z[:] = disc.phi @ z + disc.hold * w_start + disc.ramp * slope


def filter_acceleration(z: np.ndarray, disc: FilterDiscretisation, w_now: float) -> float:
    """w_f'' = wn^2 (w - w_f) - 2 z wn w_f' at the sample time."""
    return disc.wn_rad_s**2 * (w_now - z[0]) - 2.0 * disc.zeta * disc.wn_rad_s * z[1]


def friction_shape(v_m_s: np.ndarray | float, slope_s_per_m: float = 9000.0) -> np.ndarray | float:
    """Sf(v) = (2/pi) atan(9000 v): the controller's smooth Coulomb model."""
    return (2.0 / np.pi) * np.arctan(slope_s_per_m * v_m_s)


def project_box(theta: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Element-wise projection onto the box (eq. 9 for a diagonal gain)."""
    return np.minimum(np.maximum(theta, lower), upper)


def project_metric(
    y: np.ndarray, gamma: np.ndarray, lower: np.ndarray, upper: np.ndarray, max_iterations: int = 50
) -> np.ndarray:
    """argmin over the box of (x - y)^T Gamma^-1 (x - y): the discrete eq. (16).

    Primal active-set method. With the active set A held at its bounds b_A,
    the free part is the conditional mean x_F = y_F + Gamma_FA Gamma_AA^-1
    (b_A - y_A), so Gamma^-1 is never formed. The gradient g = Gamma^-1 (x - y)
    is zero on F and g_A = Gamma_AA^-1 (x - y)_A; KKT needs g_i <= 0 at an
    upper bound and g_i >= 0 at a lower one. Several faces may be active.
    """
    n = y.shape[0]
    inside = (y >= lower) & (y <= upper)
    if inside.all():
        return y.copy()
    active = ~inside
    bound = np.where(y > upper, upper, lower)
    x = y.copy()
    for _ in range(max_iterations):
        a_idx = np.flatnonzero(active)
        f_idx = np.flatnonzero(~active)
        x = y.copy()
        x[a_idx] = bound[a_idx]
        if a_idx.size:
            delta = np.linalg.solve(gamma[np.ix_(a_idx, a_idx)], x[a_idx] - y[a_idx])
            x[f_idx] = y[f_idx] + gamma[np.ix_(f_idx, a_idx)] @ delta
        else:
            delta = np.zeros(0)
        # Free variables that left the box become active at the bound they crossed.
        over = (~active) & ((x > upper) | (x < lower))
        if over.any():
            # Add only the worst violator: adding all at once can overshoot.
            violation = np.where(x > upper, x - upper, lower - x)
            violation[~over] = -np.inf
            i = int(np.argmax(violation))
            active[i] = True
            bound[i] = upper[i] if x[i] > upper[i] else lower[i]
            continue
        # Active variables whose multiplier has the wrong sign are released.
        wrong = np.zeros(n)
        for j, i in enumerate(a_idx):
            g = delta[j]
            wrong[i] = g if bound[i] == upper[i] else -g  # > 0 means wrong sign
        if a_idx.size and wrong.max() > 1e-15 * max(1.0, np.abs(delta).max()):
            active[int(np.argmax(wrong))] = False
            continue
        return np.minimum(np.maximum(x, lower), upper)
    raise RuntimeError("project_metric: active-set loop did not converge")


@dataclass(frozen=True)
class LeastSquaresSettings:
    """Least squares with covariance limiting (eq. 27-28), paper values."""

    nu: float = 0.1
    kappa: float = 0.1
    rho_max: float = 500.0
    gamma0_diag: tuple[float, ...] = (10.0, 10.0, 10.0, 10.0, 10.0, 10.0, 5000.0, 5000.0)


def least_squares_step(
    theta: np.ndarray,
    gamma: np.ndarray,
    regressor: np.ndarray,
    target: np.ndarray,
    settings: LeastSquaresSettings,
    lower: np.ndarray,
    upper: np.ndarray,
    sample_period_s: float,
) -> float:
    """One sample of eq. (27)-(28) with projection; updates theta, gamma in place.

    regressor: gamma_f, shape (p, m) (here 8 x 2); target: u_f, shape (m,).
    The information term is applied in its exact discrete (inverse-update)
    form, Gamma+^-1 = Gamma^-1 + Ts gamma_f gamma_f^T / n, which keeps Gamma
    symmetric positive definite for any step; forgetting multiplies Gamma by
    exp(kappa Ts) only while lambda_max(Gamma) <= rho_M. Returns
    lambda_max(Gamma) after the update.
    """
    g = regressor
    gamma_g = gamma @ g
    n = 1.0 + settings.nu * float(np.trace(g.T @ gamma_g))
    zeta = g.T @ theta - target
    tau = -(g @ zeta) / n
    y = theta + sample_period_s * (gamma @ tau)
    theta[:] = project_metric(y, gamma, lower, upper)

    inner = (n / sample_period_s) * np.eye(g.shape[1]) + g.T @ gamma_g
    gamma -= gamma_g @ np.linalg.solve(inner, gamma_g.T)
    lam_max = float(np.linalg.eigvalsh(gamma)[-1])
    if lam_max <= settings.rho_max:
        growth = np.exp(settings.kappa * sample_period_s)
        gamma *= growth
        lam_max *= growth
    gamma[:] = 0.5 * (gamma + gamma.T)
    return lam_max
