"""Projections and least squares of DIARC's indirect estimator (eq. 9, 16, 27-28)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from gantry_twin.numerics.estimation import (
    LeastSquaresSettings,
    discretise_filter,
    filter_acceleration,
    least_squares_step,
    project_box,
    project_metric,
)

from .helpers import THETA_MAX, THETA_MIN


def random_spd(n: int, rng: np.random.Generator, condition: float = 1e3) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    eig = np.exp(rng.uniform(0.0, np.log(condition), size=n))
    return (q * eig) @ q.T


def brute_force_projection(y, gamma, lower, upper):
    """Independent solution: try every assignment of each coordinate to free/lower/upper."""
    w = np.linalg.inv(gamma)
    best, best_cost = None, np.inf
    n = y.size
    for pattern in itertools.product((0, 1, 2), repeat=n):
        fixed = np.array([p != 0 for p in pattern])
        x = y.copy()
        x[fixed] = np.where(np.array(pattern)[fixed] == 1, lower[fixed], upper[fixed])
        free = ~fixed
        if free.any():
            # minimise over free coordinates with the others fixed: W_FF x_F = W_FF y_F - W_FA (x_A - y_A)
            rhs = w[np.ix_(free, free)] @ y[free] - w[np.ix_(free, fixed)] @ (x[fixed] - y[fixed])
            x[free] = np.linalg.solve(w[np.ix_(free, free)], rhs)
        if np.all(x >= lower - 1e-12) and np.all(x <= upper + 1e-12):
            cost = (x - y) @ w @ (x - y)
            if cost < best_cost:
                best, best_cost = x, cost
    return best


@pytest.mark.parametrize("seed", range(40))
def test_metric_projection_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    n = 5
    lower = rng.uniform(-1.0, 0.0, n)
    upper = lower + rng.uniform(0.1, 1.0, n)
    gamma = random_spd(n, rng)
    y = rng.uniform(lower - 2.0, upper + 2.0)  # often several faces violated at once
    x = project_metric(y, gamma, lower, upper)
    np.testing.assert_allclose(x, brute_force_projection(y, gamma, lower, upper), atol=1e-9)


@pytest.mark.parametrize("seed", range(200))
def test_metric_projection_p4_p5(seed):
    """P4: the result is in the box. P5 (discrete form of eq. 10 with eq. 16):
    for every theta in the box, (x - theta)^T Gamma^-1 (x - y) <= 0."""
    rng = np.random.default_rng(1000 + seed)
    n = 8
    lower, upper = THETA_MIN, THETA_MAX
    gamma = random_spd(n, rng, condition=1e4)
    y = rng.uniform(lower - (upper - lower) * 3, upper + (upper - lower) * 3)
    x = project_metric(y, gamma, lower, upper)
    assert np.all(x >= lower) and np.all(x <= upper)
    w_step = np.linalg.solve(gamma, x - y)
    corners = np.where(rng.random((64, n)) < 0.5, lower, upper)
    interior = rng.uniform(lower, upper, size=(64, n))
    for theta in np.vstack([corners, interior]):
        assert (x - theta) @ w_step <= 1e-9 * (1 + np.abs(w_step).sum())


def test_metric_projection_leaves_interior_points_alone():
    rng = np.random.default_rng(20101)
    gamma = random_spd(8, rng)
    lower, upper = -np.ones(8), np.ones(8)
    y = rng.uniform(-0.9, 0.9, 8)
    np.testing.assert_array_equal(project_metric(y, gamma, lower, upper), y)


def test_metric_projection_with_diagonal_gamma_is_clipping():
    """For a diagonal Gamma, eq. (16) reduces to the element-wise eq. (9)."""
    rng = np.random.default_rng(20102)
    gamma = np.diag(rng.uniform(1, 100, 8))
    lower, upper = -np.ones(8), np.ones(8)
    y = rng.uniform(-3, 3, 8)
    np.testing.assert_allclose(project_metric(y, gamma, lower, upper), project_box(y, lower, upper))


def test_filter_discretisation_is_exact_for_ramps_and_holds():
    """FOH on a ramp input and ZOH on a held input equal the continuous solution (scipy lsim)."""
    from scipy import signal

    wn, zeta, ts = 2 * np.pi * 150, 0.7, 2e-4
    disc = discretise_filter(wn, zeta, ts)
    t = np.arange(0, 0.02 + ts / 2, ts)
    w = 0.3 * t + 0.01 * np.sin(200 * t)  # smooth input, sampled
    sys = signal.lti([wn**2], [1, 2 * zeta * wn, wn**2])
    fine = np.linspace(0, t[-1], 200 * (t.size - 1) + 1)
    _, yout, xout = signal.lsim(sys, np.interp(fine, t, w), fine)  # piecewise-linear input, fine grid
    z = np.zeros(2)
    for k in range(1, t.size):
        z = disc.phi @ z + disc.hold * w[k - 1] + disc.ramp * (w[k] - w[k - 1]) / ts
    assert z[0] == pytest.approx(yout[-1], rel=1e-6, abs=1e-12)
    accel = filter_acceleration(z, disc, w[-1])
    d2 = np.gradient(np.gradient(yout, fine), fine)
    assert accel == pytest.approx(d2[-3], rel=2e-3)


def test_least_squares_keeps_gamma_spd_and_recovers_parameters():
    """Noise-free linear regression u = g^T theta: estimates converge, Gamma stays SPD."""
    settings = LeastSquaresSettings()
    lower, upper = THETA_MIN, THETA_MAX
    true = np.array([0.12, 0.5, 0.5, 0.7, 0.1, 0.15, 0.02, -0.03])
    theta = np.array([0.1, 0.55, 0.35, 0.5, 0.1, 0.15, 0.0, 0.0])
    gamma = np.diag(settings.gamma0_diag).astype(float)
    for k in range(40000):
        t = k * 2e-4
        g = np.zeros((8, 2))
        g[0, 0], g[1, 1] = 2 * np.sin(3 * t), 1.5 * np.cos(2 * t)
        g[2, 0], g[3, 1] = np.cos(3 * t), np.sin(2 * t + 0.3)
        g[4, 0], g[5, 1] = np.tanh(5 * np.sin(5 * t)), np.tanh(5 * np.cos(7 * t))
        g[6, 0] = g[7, 1] = -1.0
        lam = least_squares_step(theta, gamma, g, g.T @ true, settings, lower, upper, 2e-4)
        assert np.all(theta >= lower) and np.all(theta <= upper)
    eig = np.linalg.eigvalsh(gamma)
    assert eig.min() > 0 and np.allclose(gamma, gamma.T)
    assert lam == pytest.approx(eig.max())
    np.testing.assert_allclose(theta, true, rtol=0.02, atol=2e-3)


def _pool_sizes(libraries) -> list[int]:  # noqa: ANN001
    names = ("scipy_openblas_get_num_threads", "scipy_openblas_get_num_threads64_", "openblas_get_num_threads")
    return [int(getattr(lib, next(n for n in names if hasattr(lib, n)))()) for lib in libraries]


def test_one_blas_thread_holds_each_openblas_to_one_thread_and_restores_it():
    from gantry_twin.numerics import linalg

    with linalg.one_blas_thread():
        libraries = linalg._OPENBLAS
        inside = _pool_sizes(libraries)
    if not libraries:
        pytest.skip("no OpenBLAS library with a thread-local thread count next to numpy / scipy")
    assert inside == [1] * len(libraries)
    before = _pool_sizes(libraries)
    with linalg.one_blas_thread():
        pass
    assert _pool_sizes(libraries) == before


def test_filter_discretisation_runs_lapack_on_one_thread(monkeypatch):
    """scipy's expm (LAPACK) at a DIARC reset would leave OpenBLAS threads spinning beside the loop."""
    import contextlib

    from gantry_twin.numerics import estimation

    entered = []

    @contextlib.contextmanager
    def recording():
        entered.append(True)
        yield

    monkeypatch.setattr(estimation, "one_blas_thread", recording)
    disc = discretise_filter(2 * np.pi * 250.0, 0.7, 2e-4)
    assert entered == [True]
    monkeypatch.undo()
    assert np.array_equal(discretise_filter(2 * np.pi * 250.0, 0.7, 2e-4).phi, disc.phi)
