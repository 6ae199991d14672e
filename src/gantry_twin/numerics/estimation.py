"""DIARC's indirect estimator and the projections (paper eq. 8-9, 16, 25-28).

Owns the filters Hf of eq. (25), discretised exactly (the position with a
first-order hold, the held inputs with a zero-order hold), their steady-state
start, the least squares of eq. (27-28) and the projections (eq. 9, 16): the
equations are in docs/equations.md ("The estimator"). The per-sample kernels
serve DIARC's step; :func:`filter_run` and :func:`filter_axis` run the same
filters over whole signals (excitation, identification). Cholesky and
lambda_max are in :mod:`gantry_twin.numerics.linalg`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.linalg import expm

from gantry_twin.numerics.jit import kernel, reference
from gantry_twin.numerics.linalg import (
    cholesky_factor,
    cholesky_solve,
    cholesky_substitute,
    largest_eigenvalue,
    one_blas_thread,
)
from gantry_twin.settings import Range, Vector, validated
from gantry_twin.theta import AXES, THETA_NAMES

#: The slope of the paper's smooth Coulomb shape Sf(v) = (2/pi) atan(9000 v), s/m (section 5).
FRICTION_SLOPE_S_M = 9000.0

# The ranges of the estimator's settings: each bound and its reason, with the runs that show it, is in
# docs/scenarios.md ("Why these ranges").

#: Sf(v)'s slope, s/m: from 100 (Sf within 2 % of sign(v) at the contour's 0.4 m/s, so Af is not confused
#: with B) to 1e6 (Sf switches within 1 um/s, far below the encoder's velocity step).
FrictionSlope = Range(100.0, 1.0e6, "s/m")
#: Natural frequencies of Hf per axis (X, Y), Hz: above the fastest contour (rate_rad_s 20 = 3.2 Hz),
#: so that Hf passes the motion it filters; at most a tenth of the 5 kHz sample rate, where x_f'' =
#: wn^2 (x - x_f) - ... becomes mostly encoder quantisation.
FilterHz = Vector(Range(5.0, 500.0, "Hz"), AXES)
#: Hf's damping ratio: from 0.1 (below, Hf rings at wn with a gain over 5) to 5 (an overdamped
#: filter whose slow pole is wn / (2 zeta): a lower filter frequency in disguise).
FilterZeta = Range(0.1, 5.0)
#: The paper's Hf (section 5): 250 Hz on X, 150 Hz on Y, damping 0.7.
PAPER_FILTER_HZ = (250.0, 150.0)
PAPER_FILTER_ZETA = 0.7


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
    with one_blas_thread():  # no OpenBLAS thread left spinning beside the loop that follows
        e = expm(aug * sample_period_s)
    return FilterDiscretisation(e[:2, :2].copy(), e[:2, 2].copy(), e[:2, 3].copy(), wn_rad_s, zeta)


@kernel(inline=True)
def filter_advance(z, column, phi, hold, ramp, w_start, slope):
    """Advance the filter state z[:, column] = [w_f, w_f'] in place over one sample.

    The input is w_start at the start of the sample and grows at ``slope``
    (units/s) through it; slope = 0 is a zero-order hold. phi, hold, ramp
    come from :func:`discretise_filter`.
    """
    w0, w1 = z[0, column], z[1, column]
    z[0, column] = phi[0, 0] * w0 + phi[0, 1] * w1 + hold[0] * w_start + ramp[0] * slope
    z[1, column] = phi[1, 0] * w0 + phi[1, 1] * w1 + hold[1] * w_start + ramp[1] * slope


@kernel
def filter_run(z, column, phi, hold, ramp, w_start, slope, out):
    """Advance z[:, column] through len(w_start) samples; out[k] (n, 2) is [w_f, w_f'] after sample k.

    w_start[k], slope[k]: the input at the start of sample k and its slope
    through it (see :func:`filter_advance`, which does each sample).
    """
    for k in range(w_start.shape[0]):
        filter_advance(z, column, phi, hold, ramp, w_start[k], slope[k])
        out[k, 0] = z[0, column]
        out[k, 1] = z[1, column]


@kernel
def filtered_acceleration(w_f, dw_f, wn_rad_s, zeta, w_now):
    """w_f'' = wn^2 (w - w_f) - 2 z wn w_f' at the sample time."""
    return wn_rad_s * wn_rad_s * (w_now - w_f) - 2.0 * zeta * wn_rad_s * dw_f


@kernel(inline=True)
def filter_start(z, wn_rad_s, zeta, q_m, v_m_s):
    """Hf (eq. 25) in steady state for a position moving at v: column 0 of z (2, k) becomes (w_f, w_f') =
    (q - (2 zeta / wn) v, v). A held input's column is (value, 0), set by the caller. The estimator's start
    and the offline filters (:func:`filter_steady_state`) both use it."""
    lag = 2.0 * zeta / wn_rad_s
    z[0, 0] = q_m - lag * v_m_s
    z[1, 0] = v_m_s


def filter_steady_state(disc: FilterDiscretisation, q_m: float, v_m_s: float, held: Sequence[float]) -> np.ndarray:
    """Filter states (2, 1 + k) of one axis in steady state: the position moving at v, the k inputs held.

    Columns as :func:`filter_axis` keeps them: [q, held...]; rows [w_f, w_f'].
    """
    z = np.zeros((2, 1 + len(held)))
    reference(filter_start)(z, disc.wn_rad_s, disc.zeta, q_m, v_m_s)
    z[0, 1:] = held
    return z


def filter_axis(
    z: np.ndarray, disc: FilterDiscretisation, q: np.ndarray, prev: np.ndarray, held: np.ndarray, ts: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Advance one axis' filter states z (2, 1 + k) in place through n samples, as DIARC's estimator does.

    Sample j: the position rises linearly from prev[j] to q[j] (first-order
    hold), the k inputs held[j] (n, k) are held (zero-order hold). Returns
    x_f'' (n,) at the sample time, x_f' (n,) and the filtered inputs (n, k).
    """
    n = q.shape[0]
    zq, scratch = np.empty((n, 2)), np.empty((n, 2))
    filtered = np.empty((n, held.shape[1]))
    zero = np.zeros(n)
    filter_run(z, 0, disc.phi, disc.hold, disc.ramp, np.ascontiguousarray(prev), (q - prev) / ts, zq)
    for j in range(held.shape[1]):
        filter_run(z, 1 + j, disc.phi, disc.hold, disc.ramp, np.ascontiguousarray(held[:, j]), zero, scratch)
        filtered[:, j] = scratch[:, 0]
    return filtered_acceleration(zq[:, 0], zq[:, 1], disc.wn_rad_s, disc.zeta, q), zq[:, 1].copy(), filtered


def filter_acceleration(z: np.ndarray, disc: FilterDiscretisation, w_now: float) -> float:
    """w_f'' of the filter state z = [w_f, w_f'] (see :func:`filtered_acceleration`)."""
    return filtered_acceleration(float(z[0]), float(z[1]), disc.wn_rad_s, disc.zeta, float(w_now))


@kernel
def friction_shape(v_m_s, slope_s_per_m=FRICTION_SLOPE_S_M):
    """Sf(v) = (2/pi) atan(9000 v): the controller's smooth Coulomb model (m/s; a number or an array)."""
    return (2.0 / np.pi) * np.arctan(slope_s_per_m * v_m_s)


@kernel
def clip(value, lower, upper):
    """value limited to [lower, upper]; NaN passes through (so the loop can stop on it)."""
    if value > upper:
        return upper
    if value < lower:
        return lower
    return value


@kernel
def project_box(theta, lower, upper, out=None):
    """Element-wise projection onto the box (eq. 9 for a diagonal gain)."""
    if out is None:
        out = np.empty(theta.shape[0])
    for i in range(theta.shape[0]):
        out[i] = clip(theta[i], lower[i], upper[i])
    return out


class ProjectionWork(NamedTuple):
    """Scratch arrays of :func:`project_metric_into` for p parameters."""

    active: np.ndarray  # (p,) 1 where the variable sits on a bound
    bound: np.ndarray  # (p,) the bound it sits on
    active_index: np.ndarray  # (p,) int
    free_index: np.ndarray  # (p,) int
    gamma_aa: np.ndarray  # (p, p) Gamma restricted to the active set
    rhs: np.ndarray  # (p,)
    delta: np.ndarray  # (p,) Gamma_AA^-1 (x - y)_A
    factor: np.ndarray  # (p, p) Cholesky scratch


def projection_work(p: int) -> ProjectionWork:
    """Preallocated scratch for :func:`project_metric_into`."""
    return ProjectionWork(
        np.zeros(p),
        np.zeros(p),
        np.zeros(p, dtype=np.int64),
        np.zeros(p, dtype=np.int64),
        np.zeros((p, p)),
        np.zeros(p),
        np.zeros(p),
        np.zeros((p, p)),
    )


@kernel(nrt=False)
def project_metric_into(y, gamma, lower, upper, max_iterations, x, work):
    """x = argmin over the box of (x - y)^T Gamma^-1 (x - y): the discrete eq. (16).

    Primal active-set method. With the active set A held at its bounds b_A,
    the free part is the conditional mean x_F = y_F + Gamma_FA Gamma_AA^-1
    (b_A - y_A), so Gamma^-1 is never formed. The gradient g = Gamma^-1 (x - y)
    is zero on F and g_A = Gamma_AA^-1 (x - y)_A; KKT needs g_i <= 0 at an
    upper bound and g_i >= 0 at a lower one. Several faces may be active.
    Free variables that leave the box join A one at a time (the worst first:
    adding all at once can overshoot); an active variable whose multiplier
    has the wrong sign leaves A.
    """
    # Unpacked once: each namedtuple field access costs a reference-count update in numba.
    active, bound, active_index, free_index, gamma_aa, rhs, delta, factor = work
    n = y.shape[0]
    inside = True
    for i in range(n):
        outside = y[i] > upper[i] or y[i] < lower[i]
        active[i] = 1.0 if outside else 0.0
        bound[i] = upper[i] if y[i] > upper[i] else lower[i]
        inside = inside and not outside
    if inside:
        for i in range(n):
            x[i] = y[i]
        return
    for _ in range(max_iterations):
        n_active = 0
        n_free = 0
        for i in range(n):
            x[i] = y[i]
            if active[i] > 0.0:
                x[i] = bound[i]
                active_index[n_active] = i
                n_active += 1
            else:
                free_index[n_free] = i
                n_free += 1
        if n_active > 0:
            for j in range(n_active):
                aj = active_index[j]
                rhs[j] = x[aj] - y[aj]
                for m in range(n_active):
                    gamma_aa[j, m] = gamma[aj, active_index[m]]
            cholesky_solve(gamma_aa, n_active, rhs, delta, factor)
            for j in range(n_free):
                f = free_index[j]
                acc = 0.0
                for m in range(n_active):
                    acc += gamma[f, active_index[m]] * delta[m]
                x[f] = y[f] + acc
        # Free variables that left the box: the worst violator becomes active.
        worst = -1
        worst_violation = 0.0
        for j in range(n_free):
            f = free_index[j]
            violation = x[f] - upper[f] if x[f] > upper[f] else (lower[f] - x[f] if x[f] < lower[f] else 0.0)
            if violation > 0.0 and (worst < 0 or violation > worst_violation):
                worst, worst_violation = f, violation
        if worst >= 0:
            active[worst] = 1.0
            bound[worst] = upper[worst] if x[worst] > upper[worst] else lower[worst]
            continue
        # Active variables whose multiplier has the wrong sign are released.
        release = -1
        most_wrong = 0.0
        scale = 1.0
        for j in range(n_active):
            scale = max(scale, abs(delta[j]))
        for j in range(n_active):
            a = active_index[j]
            wrong = delta[j] if bound[a] == upper[a] else -delta[j]  # > 0: wrong sign
            if wrong > 1e-15 * scale and (release < 0 or wrong > most_wrong):
                release, most_wrong = a, wrong
        if release >= 0:
            active[release] = 0.0
            continue
        for i in range(n):
            x[i] = clip(x[i], lower[i], upper[i])
        return
    raise RuntimeError("project_metric: active-set loop did not converge")


def project_metric(
    y: np.ndarray, gamma: np.ndarray, lower: np.ndarray, upper: np.ndarray, max_iterations: int = 50
) -> np.ndarray:
    """argmin over the box of (x - y)^T Gamma^-1 (x - y); see :func:`project_metric_into`."""
    y = np.ascontiguousarray(y, dtype=float)
    x = np.empty_like(y)
    args = (np.ascontiguousarray(gamma, dtype=float), np.asarray(lower, dtype=float), np.asarray(upper, dtype=float))
    project_metric_into(y, *args, int(max_iterations), x, projection_work(y.shape[0]))
    return x


@validated("least_squares")
class LeastSquaresSettings:
    """Least squares with covariance limiting (eq. 27-28), paper values."""

    #: n = 1 + nu tr(gamma_f^T Gamma gamma_f): a larger nu divides the step until the estimates freeze.
    nu: Range(0.0, 1.0) = 0.1
    #: Forgetting rate, 1/s: a memory 1/kappa of at least 10 ms (50 samples).
    kappa: Range(0.0, 100.0, "1/s") = 0.1
    #: Cap of lambda_max(Gamma): Gamma's spread stays well inside float64 in the eq. (28) downdate.
    rho_max: Range(0.0, 1.0e8, lo_open=True) = 500.0
    #: Gamma(0): from 0.1 (below, theta^ hardly leaves theta0) to rho_max's cap.
    gamma0_diag: Vector(Range(0.1, 1.0e8), THETA_NAMES) = (10.0, 10.0, 10.0, 10.0, 10.0, 10.0, 5000.0, 5000.0)


class LeastSquaresWork(NamedTuple):
    """Scratch arrays of :func:`least_squares_update` for p parameters and m outputs."""

    gamma_g: np.ndarray  # (p, m) Gamma gamma_f
    zeta: np.ndarray  # (m,) prediction error
    tau: np.ndarray  # (p,)
    y: np.ndarray  # (p,) the unprojected new estimate
    inner: np.ndarray  # (m, m)
    column: np.ndarray  # (m,)
    solved: np.ndarray  # (m, p) inner^-1 (Gamma gamma_f)^T
    lambda_bound: np.ndarray  # (1,) an upper bound of lambda_max(Gamma): the last one computed
    eigvecs: np.ndarray  # (2, p) near Gamma's top two eigenvectors: largest_eigenvalue's warm start
    eig_scratch: np.ndarray  # (2, p)
    tridiagonal: np.ndarray  # (p, p) scratch of largest_eigenvalue
    diag: np.ndarray  # (p,)
    off: np.ndarray  # (p,)
    scratch: np.ndarray  # (p,)
    projection: ProjectionWork


def least_squares_work(p: int, m: int, gamma: np.ndarray | None = None) -> LeastSquaresWork:
    """Scratch for :func:`least_squares_update`; the eigenvector warm start from ``gamma`` if given."""
    # Warm start: the unit vectors of Gamma's two largest diagonal entries (its top
    # eigenvectors when Gamma is diagonal, as Gamma(0) is). No LAPACK call: OpenBLAS
    # threads would then spin on the second core while the loop runs.
    diagonal = np.ones(p) if gamma is None else np.diag(gamma)
    order = np.argsort(-diagonal, kind="stable")
    eigvecs = np.zeros((2, p))
    eigvecs[0, order[0]] = eigvecs[1, order[1]] = 1.0
    return LeastSquaresWork(
        np.zeros((p, m)),
        np.zeros(m),
        np.zeros(p),
        np.zeros(p),
        np.zeros((m, m)),
        np.zeros(m),
        np.zeros((m, p)),
        np.array([np.inf]),
        eigvecs,
        np.zeros((2, p)),
        np.zeros((p, p)),
        np.zeros(p),
        np.zeros(p),
        np.zeros(p),
        projection_work(p),
    )


@kernel(nrt=False)
def least_squares_update(theta, gamma, g, target, nu, kappa, rho_max, lower, upper, sample_period_s, work):
    """One sample of eq. (27)-(28) with projection; updates theta, gamma in place.

        n      = 1 + nu tr(gamma_f^T Gamma gamma_f)
        zeta   = gamma_f^T theta^ - u_f,  tau = -gamma_f zeta / n
        theta^ = Proj_Gamma(theta^ + Ts Gamma tau)                    (eq. 16, 27)
        Gamma  = Gamma - Gamma g (n/Ts I + g^T Gamma g)^-1 g^T Gamma  (eq. 28)

    g: gamma_f, shape (p, m) (here 8 x 2); target: u_f, shape (m,). The
    information term is applied in its exact discrete (inverse-update) form,
    Gamma+^-1 = Gamma^-1 + Ts gamma_f gamma_f^T / n, which keeps Gamma
    symmetric positive definite for any step (Gamma must be exactly
    symmetric on entry; the update keeps it so); forgetting multiplies Gamma by
    exp(kappa Ts) only while lambda_max(Gamma) <= rho_M. Returns
    lambda_max(Gamma) after the update (:func:`largest_eigenvalue`: relative
    accuracy EIGENVALUE_TOLERANCE, certified).
    """
    p, m = g.shape
    (
        gamma_g,
        zeta,
        tau,
        y,
        inner,
        column,
        solved,
        lambda_bound,
        eigvecs,
        eig_scratch,
        tridiagonal,
        diag,
        off,
        scratch,
        projection,
    ) = work
    trace = 0.0
    for i in range(p):
        for j in range(m):
            acc = 0.0
            for k in range(p):
                acc += gamma[i, k] * g[k, j]
            gamma_g[i, j] = acc
            trace += g[i, j] * acc
    n = 1.0 + nu * trace
    for j in range(m):
        acc = 0.0
        for i in range(p):
            acc += g[i, j] * theta[i]
        zeta[j] = acc - target[j]
    for i in range(p):
        acc = 0.0
        for j in range(m):
            acc += g[i, j] * zeta[j]
        tau[i] = -acc / n
    for i in range(p):
        acc = 0.0
        for k in range(p):
            acc += gamma[i, k] * tau[k]
        y[i] = theta[i] + sample_period_s * acc
    project_metric_into(y, gamma, lower, upper, 50, theta, projection)

    for j in range(m):
        for k in range(m):
            acc = n / sample_period_s if j == k else 0.0
            for i in range(p):
                acc += g[i, j] * gamma_g[i, k]
            inner[j, k] = acc
    factor = projection.factor
    if not cholesky_factor(inner, m, factor):
        raise np.linalg.LinAlgError("least_squares_update: n/Ts I + g^T Gamma g is not positive definite")
    for i in range(p):
        for j in range(m):
            column[j] = gamma_g[i, j]
        cholesky_substitute(factor, m, column, scratch)
        for j in range(m):
            solved[j, i] = scratch[j]
    # The downdate is symmetric: compute the lower triangle and mirror it (Gamma stays exactly symmetric).
    for i in range(p):
        for k in range(i + 1):
            acc = 0.0
            for j in range(m):
                acc += gamma_g[i, j] * solved[j, k]
            gamma[i, k] -= acc
            gamma[k, i] = gamma[i, k]
    # The information term only shrinks Gamma: the last lambda_max bounds the new one (rounding aside).
    lam_max = largest_eigenvalue(gamma, eigvecs, eig_scratch, tridiagonal, diag, off, lambda_bound[0] * (1.0 + 1e-12))
    if lam_max <= rho_max:
        growth = math.exp(kappa * sample_period_s)
        for i in range(p):
            for k in range(p):
                gamma[i, k] *= growth
        lam_max *= growth
    lambda_bound[0] = lam_max
    return lam_max


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
    """One sample of eq. (27)-(28); see :func:`least_squares_update`. Returns lambda_max(Gamma)."""
    g = np.ascontiguousarray(regressor, dtype=float)
    work = least_squares_work(g.shape[0], g.shape[1], gamma)
    return least_squares_update(
        theta,
        gamma,
        g,
        np.asarray(target, dtype=float),
        float(settings.nu),
        float(settings.kappa),
        float(settings.rho_max),
        np.asarray(lower, dtype=float),
        np.asarray(upper, dtype=float),
        float(sample_period_s),
        work,
    )
