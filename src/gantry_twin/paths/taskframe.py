"""The task-coordinate frame attached to the desired contour (paper eq. 1, 4).

The equations (docs/equations.md, the task frame and the error dynamics):

    T(alpha) = [[-sin a, cos a], [cos a, sin a]],   T = T^T = T^-1
    eps = T e = [eps_n, eps_t],  e = q - q_d
    T'  = alpha' R,  R = [[-cos a, -sin a], [-sin a, cos a]],  T R = J = [[0, 1], [-1, 0]]
    T'' = alpha'' R - alpha'^2 T
    s_c = e' + L e,   L = alpha' J + T Lambda T
    L'  = alpha'' J + T' Lambda T + T Lambda T'

Lambda = diag(lambda_n, lambda_t) acts in the task frame; s = T s_c.
The per-sample functions are numba kernels (:mod:`gantry_twin.numerics.jit`): they
take one sample (scalar alpha, 2-vectors) and write into ``out`` arrays when
given, so the compiled 0.2 ms loop allocates nothing; called without ``out``
they return new arrays.
"""

from __future__ import annotations

import math

import numpy as np

from gantry_twin.numerics.jit import kernel

#: T R, the constant skew matrix of the frame's rotation.
J = np.array([[0.0, 1.0], [-1.0, 0.0]])


@kernel
def frame(alpha, out=None):
    """T(alpha), eq. (1): rows are the normal and tangent directions."""
    if out is None:
        out = np.empty((2, 2))
    s, c = math.sin(alpha), math.cos(alpha)
    out[0, 0], out[0, 1] = -s, c
    out[1, 0], out[1, 1] = c, s
    return out


@kernel
def frame_rate_basis(alpha, out=None):
    """R(alpha) = dT/dalpha."""
    if out is None:
        out = np.empty((2, 2))
    s, c = math.sin(alpha), math.cos(alpha)
    out[0, 0], out[0, 1] = -c, -s
    out[1, 0], out[1, 1] = -s, c
    return out


def frame_derivatives(alpha: float, dalpha: float, ddalpha: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """T, T' and T'' (eq. 4) for the tangent angle and its time derivatives."""
    t = frame(alpha)
    r = frame_rate_basis(alpha)
    return t, dalpha * r, ddalpha * r - dalpha * dalpha * t


@kernel
def error_gains(alpha, dalpha, ddalpha, lam, t=None, big_l=None, big_l_dot=None):
    """T, L and L' of the error dynamics (docs/equations.md; lam = [lambda_n, lambda_t], 1/s).

    L = alpha' J + T Lambda T and L' = alpha'' J + T' Lambda T + T Lambda T',
    with T' = alpha' R.
    """
    if t is None:
        t = np.empty((2, 2))
    if big_l is None:
        big_l = np.empty((2, 2))
    if big_l_dot is None:
        big_l_dot = np.empty((2, 2))
    s, c = math.sin(alpha), math.cos(alpha)
    t[0, 0], t[0, 1], t[1, 0], t[1, 1] = -s, c, c, s
    # T' = alpha' R
    d00, d01, d10, d11 = -dalpha * c, -dalpha * s, -dalpha * s, dalpha * c
    l0, l1 = lam[0], lam[1]
    j = ((0.0, 1.0), (-1.0, 0.0))
    for row in range(2):
        for col in range(2):
            t_lam_t = t[row, 0] * l0 * t[0, col] + t[row, 1] * l1 * t[1, col]
            big_l[row, col] = dalpha * j[row][col] + t_lam_t
    dt = ((d00, d01), (d10, d11))
    for row in range(2):
        for col in range(2):
            dt_lam_t = dt[row][0] * l0 * t[0, col] + dt[row][1] * l1 * t[1, col]
            t_lam_dt = t[row, 0] * l0 * dt[0][col] + t[row, 1] * l1 * dt[1][col]
            big_l_dot[row, col] = ddalpha * j[row][col] + dt_lam_t + t_lam_dt
    return t, big_l, big_l_dot


@kernel
def sliding_variable(e, de, big_l, out=None):
    """Cartesian s_c = e' + L e (eq. 11 expressed in X, Y; s = T s_c)."""
    if out is None:
        out = np.empty(2)
    for row in range(2):
        out[row] = de[row] + (big_l[row, 0] * e[0] + big_l[row, 1] * e[1])
    return out


def task_errors(alpha: np.ndarray, e: np.ndarray) -> np.ndarray:
    """eps = T e for arrays of samples: alpha (N,), e (N, 2) -> (N, 2) [eps_n, eps_t]."""
    s, c = np.sin(alpha), np.cos(alpha)
    eps_n = -s * e[..., 0] + c * e[..., 1]
    eps_t = c * e[..., 0] + s * e[..., 1]
    return np.stack([eps_n, eps_t], axis=-1)


@kernel(nrt=False)
def normal_errors(alpha, q_m, q_d_m, e_m, eps_n_m):
    """e = q - q_d (n, 2) m and eps_n, the first row of eps = T e (n,) m, for n samples (into e_m, eps_n_m)."""
    for k in range(alpha.shape[0]):
        e0 = q_m[k, 0] - q_d_m[k, 0]
        e1 = q_m[k, 1] - q_d_m[k, 1]
        e_m[k, 0] = e0
        e_m[k, 1] = e1
        eps_n_m[k] = -math.sin(alpha[k]) * e0 + math.cos(alpha[k]) * e1
