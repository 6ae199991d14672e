"""The task frame (paper eq. 1, 4; docs/equations.md, the task frame).

s_c is checked against an independent route: eps = T e is formed along a smooth
random trajectory, differentiated by central differences, and s = eps' +
Lambda eps is rotated back with T. eps_n is checked against the true
contouring error of paths.contour_error (itself checked against brute force in
test_contours.py).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gantry_twin.paths.contours import TimingLaw, circle, contour_error, paper_ellipse, reference
from gantry_twin.paths.taskframe import (
    J,
    error_gains,
    frame,
    frame_derivatives,
    frame_rate_basis,
    sliding_variable,
    task_errors,
)

LAMBDA = np.array([100.0, 30.0])  # 1/s, the controllers' default Lambda
PATHS = {"circle": (circle(), 2.0), "ellipse": (paper_ellipse(), 3.0)}
RNG_SEED = 20100402
H_T = 1e-6  # s

angles = st.floats(min_value=-20.0, max_value=20.0, allow_nan=False, allow_infinity=False)


@given(angles)
def test_frame_is_symmetric_and_its_own_inverse(alpha: float) -> None:
    t = frame(alpha)
    np.testing.assert_allclose(t, t.T, atol=1e-15)
    np.testing.assert_allclose(t @ t, np.eye(2), atol=1e-15)
    np.testing.assert_allclose(np.linalg.inv(t), t, atol=1e-14)
    # Rows: the left normal and the tangent of a curve heading along alpha.
    np.testing.assert_allclose(t[1], [np.cos(alpha), np.sin(alpha)], atol=1e-15)
    np.testing.assert_allclose(t[0], [-np.sin(alpha), np.cos(alpha)], atol=1e-15)


@given(angles)
def test_rate_basis_is_dT_dalpha_and_T_R_is_J(alpha: float) -> None:
    h = 1e-6
    fd = (frame(alpha + h) - frame(alpha - h)) / (2 * h)
    np.testing.assert_allclose(frame_rate_basis(alpha), fd, atol=1e-9)
    np.testing.assert_allclose(frame(alpha) @ frame_rate_basis(alpha), J, atol=1e-15)


def smooth_alpha(t: np.ndarray, coeffs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A smooth random angle history and its exact first two time derivatives."""
    a0, a1, a2, w = coeffs
    alpha = a0 + a1 * t + a2 * np.sin(w * t)
    return alpha, a1 + a2 * w * np.cos(w * t), -a2 * w * w * np.sin(w * t)


def frame_at(t_s: float, coeffs: np.ndarray) -> np.ndarray:
    return frame(smooth_alpha(np.array([t_s]), coeffs)[0][0])


def frame_rate_at(t_s: float, coeffs: np.ndarray) -> np.ndarray:
    alpha, dalpha, ddalpha = (x[0] for x in smooth_alpha(np.array([t_s]), coeffs))
    return frame_derivatives(alpha, dalpha, ddalpha)[1]


def test_frame_time_derivatives_match_finite_differences() -> None:
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(50):
        coeffs = np.array([rng.uniform(-3, 3), rng.uniform(-5, 5), rng.uniform(-2, 2), rng.uniform(0.5, 8)])
        t0 = rng.uniform(0, 3)
        (alpha,), (dalpha,), (ddalpha,) = smooth_alpha(np.array([t0]), coeffs)
        _, dt, ddt = frame_derivatives(alpha, dalpha, ddalpha)
        fd_dt = (frame_at(t0 + H_T, coeffs) - frame_at(t0 - H_T, coeffs)) / (2 * H_T)
        fd_ddt = (frame_rate_at(t0 + H_T, coeffs) - frame_rate_at(t0 - H_T, coeffs)) / (2 * H_T)
        np.testing.assert_allclose(dt, fd_dt, atol=1e-6)
        np.testing.assert_allclose(ddt, fd_ddt, atol=1e-5)


@pytest.mark.parametrize("start", ["on_path", "rest"])
@pytest.mark.parametrize("name", PATHS)
def test_sliding_variable_is_T_times_task_frame_s(name: str, start: str) -> None:
    """s_c = e' + L e equals T (eps' + Lambda eps), eps = T e differentiated numerically.

    The actual motion q(t) is the desired one plus a smooth random error of
    tens of micrometres (the size a controller leaves), with an exact e'.
    Also checks L' against a finite difference of L.
    """
    path, rate = PATHS[name]
    timing = TimingLaw(rate, start)
    rng = np.random.default_rng(RNG_SEED)
    amp = rng.uniform(5e-6, 50e-6, (3, 2))
    freq = rng.uniform(1.0, 30.0, (3, 2))
    phase = rng.uniform(0, 2 * np.pi, (3, 2))

    def error(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        arg = freq[None] * t[:, None, None] + phase[None]
        return (amp[None] * np.sin(arg)).sum(1), (amp[None] * freq[None] * np.cos(arg)).sum(1)

    def eps(t: np.ndarray) -> np.ndarray:
        ref = reference(path, timing, t)
        return task_errors(ref.alpha, error(t)[0])

    t = np.concatenate([rng.uniform(0.01, 0.49, 20), rng.uniform(0.51, 4.0, 20)])
    ref = reference(path, timing, t)
    e, de = error(t)
    deps = (eps(t + H_T) - eps(t - H_T)) / (2 * H_T)
    s_task = deps + LAMBDA * eps(t)
    lo, hi = reference(path, timing, t - H_T), reference(path, timing, t + H_T)
    for k in range(t.size):
        tk, big_l, big_l_dot = error_gains(ref.alpha[k], ref.dalpha[k], ref.ddalpha[k], LAMBDA)
        s_c = sliding_variable(e[k], de[k], big_l)
        np.testing.assert_allclose(s_c, tk @ s_task[k], atol=1e-9)
        # And s = T s_c back in the task frame.
        np.testing.assert_allclose(tk @ s_c, s_task[k], atol=1e-9)
        l_lo = error_gains(lo.alpha[k], lo.dalpha[k], lo.ddalpha[k], LAMBDA)[1]
        l_hi = error_gains(hi.alpha[k], hi.dalpha[k], hi.ddalpha[k], LAMBDA)[1]
        np.testing.assert_allclose(big_l_dot, (l_hi - l_lo) / (2 * H_T), atol=1e-4 * max(1.0, np.abs(big_l_dot).max()))


@pytest.mark.parametrize("name", PATHS)
def test_eps_n_approximates_true_contour_error(name: str) -> None:
    """Offsets up to 50 um in random directions at many points of each contour.

    eps_n and eps_c differ by about kappa eps_t^2 / 2 (curvature kappa up to
    20 1/m on the ellipse): within 1 % of the offset everywhere, and within
    1 % of eps_c itself wherever eps_c is not a tiny fraction of the offset.
    """
    path, rate = PATHS[name]
    rng = np.random.default_rng(RNG_SEED)
    t = rng.uniform(0.0, 2 * np.pi / rate, 2000)
    ref = reference(path, TimingLaw(rate), t)
    angle = rng.uniform(0, 2 * np.pi, t.size)
    size = rng.uniform(0.0, 50e-6, t.size)
    offset = size[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    eps_n = task_errors(ref.alpha, offset)[:, 0]
    eps_c, _ = contour_error(path, ref.q_d + offset, ref.phi)
    assert np.abs(eps_c).max() > 45e-6  # the offsets really reach 50 um
    assert np.all(np.abs(eps_n - eps_c) <= 0.01 * size + 1e-12)
    clear = np.abs(eps_c) >= 5e-6
    assert clear.sum() > 1000  # most samples get the relative check
    np.testing.assert_allclose(eps_n[clear], eps_c[clear], rtol=0.01)
    # Purely normal offsets: eps_n is exact.
    normal = size[:, None] * np.stack([-np.sin(ref.alpha), np.cos(ref.alpha)], axis=1)
    eps_c_normal, _ = contour_error(path, ref.q_d + normal, ref.phi)
    np.testing.assert_allclose(task_errors(ref.alpha, normal)[:, 0], eps_c_normal, rtol=1e-6, atol=1e-12)
