"""The task-coordinate frame attached to the desired contour (paper eq. 1, 4).

Control-spec sections 4 and 5:

    T(alpha) = [[-sin a, cos a], [cos a, sin a]],   T = T^T = T^-1
    eps = T e = [eps_n, eps_t],  e = q - q_d
    T'  = alpha' R,  R = [[-cos a, -sin a], [-sin a, cos a]],  T R = J = [[0, 1], [-1, 0]]
    T'' = alpha'' R - alpha'^2 T
    s_c = e' + L e,   L = alpha' J + T Lambda T
    L'  = alpha'' J + T' Lambda T + T Lambda T'

Lambda = diag(lambda_n, lambda_t) acts in the task frame; s = T s_c.
Functions take one sample (scalar alpha, 2-vectors) so the 0.2 ms loop can
call them directly.
"""

from __future__ import annotations

import numpy as np

#: T R, the constant skew matrix of the frame's rotation.
J = np.array([[0.0, 1.0], [-1.0, 0.0]])


def frame(alpha: float) -> np.ndarray:
    """T(alpha), eq. (1): rows are the normal and tangent directions."""
    s, c = np.sin(alpha), np.cos(alpha)
    return np.array([[-s, c], [c, s]])


def frame_rate_basis(alpha: float) -> np.ndarray:
    """R(alpha) = dT/dalpha."""
    s, c = np.sin(alpha), np.cos(alpha)
    return np.array([[-c, -s], [-s, c]])


def frame_derivatives(alpha: float, dalpha: float, ddalpha: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """T, T' and T'' (eq. 4) for the tangent angle and its time derivatives."""
    t = frame(alpha)
    r = frame_rate_basis(alpha)
    return t, dalpha * r, ddalpha * r - dalpha * dalpha * t


def error_gains(
    alpha: float, dalpha: float, ddalpha: float, lam: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """T, L and L' of control-spec section 5 (lam = [lambda_n, lambda_t], 1/s)."""
    t, dt, _ = frame_derivatives(alpha, dalpha, ddalpha)
    lam_diag = np.diag(lam)
    t_lam = t @ lam_diag
    big_l = dalpha * J + t_lam @ t
    big_l_dot = ddalpha * J + dt @ lam_diag @ t + t_lam @ dt
    return t, big_l, big_l_dot


def sliding_variable(e: np.ndarray, de: np.ndarray, big_l: np.ndarray) -> np.ndarray:
    """Cartesian s_c = e' + L e (eq. 11 expressed in X, Y; s = T s_c)."""
    return de + big_l @ e


def task_errors(alpha: np.ndarray, e: np.ndarray) -> np.ndarray:
    """eps = T e for arrays of samples: alpha (N,), e (N, 2) -> (N, 2) [eps_n, eps_t]."""
    s, c = np.sin(alpha), np.cos(alpha)
    eps_n = -s * e[..., 0] + c * e[..., 1]
    eps_t = c * e[..., 0] + s * e[..., 1]
    return np.stack([eps_n, eps_t], axis=-1)
