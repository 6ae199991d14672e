"""Small dense linear algebra for the per-sample kernels: Cholesky solves and lambda_max.

Numba kernels (:mod:`gantry_twin.numerics.jit`) on float64 arrays, no LAPACK: the
matrices are 2 x 2 to 8 x 8 and change a little every 0.2 ms sample, so a
warm-started iteration beats a full decomposition (docs/performance.md), and
an OpenBLAS call would leave its threads spinning on the other core while the
loop runs. :func:`one_blas_thread` holds OpenBLAS to one thread around the
LAPACK calls made before a run (a filter's matrix exponential).
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import math
import os
from collections.abc import Iterator

import numpy as np

from gantry_twin.numerics.jit import kernel


def _openblas_libraries() -> list[ctypes.CDLL]:
    """The OpenBLAS libraries numpy's and scipy's wheels ship (``numpy.libs``, ``scipy.libs``) that can hold
    their pool to one thread for the calling thread only (``openblas_set_num_threads_local``); none elsewhere."""
    import scipy

    site = os.path.dirname(os.path.dirname(scipy.__file__))
    found = []
    for path in sorted(glob.glob(os.path.join(site, "*.libs", "*openblas*"))):
        try:
            library = ctypes.CDLL(path)
            library.openblas_set_num_threads_local.restype = ctypes.c_int
        except (OSError, AttributeError):
            continue
        found.append(library)
    return found


_OPENBLAS: list[ctypes.CDLL] | None = None


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Hold OpenBLAS to the calling thread for the calls inside (this thread only; restored after).

    For the few LAPACK calls a run makes outside the loop (scipy's ``expm`` of
    a filter at a controller's reset): a call on several threads leaves
    OpenBLAS's other threads spinning on the other cores for about 0.1 s after
    it returns, which a loop measured in process CPU time pays
    (docs/performance.md, "BLAS threads"). One thread gives the same numbers
    for these 4 x 4 matrices.
    """
    global _OPENBLAS
    if _OPENBLAS is None:
        _OPENBLAS = _openblas_libraries()
    previous = [library.openblas_set_num_threads_local(1) for library in _OPENBLAS]
    try:
        yield
    finally:
        for library, count in zip(_OPENBLAS, previous, strict=True):
            library.openblas_set_num_threads_local(count)


@kernel(inline=True)
def cholesky_factor(a, n, factor):
    """Lower Cholesky factor of a[:n, :n] into factor[:n, :n]; False if a is not positive definite."""
    for i in range(n):
        for j in range(i + 1):
            acc = a[i, j]
            for k in range(j):
                acc -= factor[i, k] * factor[j, k]
            if i == j:
                if not acc > 0.0:
                    return False
                factor[i, i] = math.sqrt(acc)
            else:
                factor[i, j] = acc / factor[j, j]
    return True


@kernel(inline=True)
def cholesky_substitute(factor, n, b, x):
    """Solve L L^T x = b[:n] with L = factor[:n, :n] from :func:`cholesky_factor`."""
    for i in range(n):
        acc = b[i]
        for k in range(i):
            acc -= factor[i, k] * x[k]
        x[i] = acc / factor[i, i]
    for i in range(n - 1, -1, -1):
        acc = x[i]
        for k in range(i + 1, n):
            acc -= factor[k, i] * x[k]
        x[i] = acc / factor[i, i]


@kernel(inline=True)
def cholesky_solve(a, n, b, x, factor):
    """Solve a[:n, :n] x = b[:n] for symmetric positive definite a (Cholesky).

    ``factor`` (at least n x n) is scratch space; x[:n] receives the solution.
    """
    if not cholesky_factor(a, n, factor):
        raise np.linalg.LinAlgError("cholesky_solve: matrix is not positive definite")
    cholesky_substitute(factor, n, b, x)


@kernel(nrt=False)
def tridiagonalise(a, t, diag, off):
    """Householder reduction of symmetric a (p x p) to tridiagonal form (same eigenvalues).

    t: (p, p) scratch (a is not modified); diag (p,) and off (p,) receive the
    diagonal and the sub-diagonal (off[p - 1] unused).
    """
    p = a.shape[0]
    for i in range(p):
        for j in range(p):
            t[i, j] = a[i, j]
    for k in range(p - 2):
        # Householder vector v (stored in off[k+1:] scratch-free: use column k of t below the diagonal).
        alpha_sq = 0.0
        for i in range(k + 1, p):
            alpha_sq += t[i, k] * t[i, k]
        if alpha_sq == 0.0:
            diag[k] = t[k, k]
            off[k] = 0.0
            continue
        alpha = -math.sqrt(alpha_sq) if t[k + 1, k] >= 0.0 else math.sqrt(alpha_sq)
        # v = x - alpha e1 (in t[k+1:, k]), beta = 2 / (v^T v)
        t[k + 1, k] -= alpha
        vtv = 0.0
        for i in range(k + 1, p):
            vtv += t[i, k] * t[i, k]
        if vtv == 0.0:
            diag[k] = t[k, k]
            off[k] = alpha
            continue
        beta = 2.0 / vtv
        # w = beta A v; then w -= (beta/2) (v^T w) v; A -= v w^T + w v^T (trailing block). w kept in t[k, k+1:].
        vw = 0.0
        for i in range(k + 1, p):
            acc = 0.0
            for j in range(k + 1, p):
                acc += t[i, j] * t[j, k]
            t[k, i] = beta * acc
            vw += t[i, k] * t[k, i]
        half = 0.5 * beta * vw
        for i in range(k + 1, p):
            t[k, i] -= half * t[i, k]
        for i in range(k + 1, p):
            for j in range(k + 1, p):
                t[i, j] -= t[i, k] * t[k, j] + t[k, i] * t[j, k]
        diag[k] = t[k, k]
        off[k] = alpha
    diag[p - 2] = t[p - 2, p - 2] if p >= 2 else 0.0
    if p >= 2:
        off[p - 2] = t[p - 1, p - 2]
    diag[p - 1] = t[p - 1, p - 1]


@kernel(nrt=False)
def largest_eigenvalue_exact(a, upper_bound, t, diag, off):
    """lambda_max of a symmetric matrix a (p x p), exact to rounding.

    Householder reduction to tridiagonal form, then Newton's method on the
    characteristic polynomial started above the largest root (the Gershgorin
    bound, or ``upper_bound`` if smaller): for a polynomial with real roots,
    Newton from the right of the largest root decreases monotonically to it.
    t (p, p), diag (p,), off (p,): scratch.
    """
    p = a.shape[0]
    tridiagonalise(a, t, diag, off)
    x = -math.inf
    for i in range(p):
        radius = (abs(off[i - 1]) if i > 0 else 0.0) + (abs(off[i]) if i < p - 1 else 0.0)
        x = max(x, diag[i] + radius)
    if upper_bound < x:
        x = upper_bound
    for _ in range(200):
        # p_k(x) = (d_k - x) p_{k-1} - e_{k-1}^2 p_{k-2} and its derivative.
        p_prev, p_cur = 1.0, diag[0] - x
        q_prev, q_cur = 0.0, -1.0
        for k in range(1, p):
            e2 = off[k - 1] * off[k - 1]
            p_next = (diag[k] - x) * p_cur - e2 * p_prev
            q_next = -p_cur + (diag[k] - x) * q_cur - e2 * q_prev
            p_prev, p_cur = p_cur, p_next
            q_prev, q_cur = q_cur, q_next
        if q_cur == 0.0:
            break
        step = p_cur / q_cur
        x -= step
        if abs(step) <= 1e-15 * abs(x):
            break
    return x


#: largest_eigenvalue's certified relative accuracy.
EIGENVALUE_TOLERANCE = 1e-10


@kernel(nrt=False)
def _orthonormalise(w, v):
    """v = Gram-Schmidt orthonormal basis of the two rows of w (2, p); False if they are dependent."""
    p = w.shape[1]
    norm = 0.0
    for i in range(p):
        norm += w[0, i] * w[0, i]
    norm = math.sqrt(norm)
    if not norm > 0.0:
        return False
    dot = 0.0
    for i in range(p):
        v[0, i] = w[0, i] / norm
        dot += v[0, i] * w[1, i]
    norm = 0.0
    for i in range(p):
        v[1, i] = w[1, i] - dot * v[0, i]
        norm += v[1, i] * v[1, i]
    norm = math.sqrt(norm)
    if not norm > 0.0:
        return False
    for i in range(p):
        v[1, i] /= norm
    # Components that have decayed to nothing are set to zero before they become
    # subnormal numbers, whose arithmetic is ~100x slower on x86.
    for r in range(2):
        for i in range(p):
            if abs(v[r, i]) < 1e-150:
                v[r, i] = 0.0
    return True


@kernel(nrt=False)
def largest_eigenvalue(a, v, w, t, diag, off, upper_bound=math.inf, iterations=12):
    """lambda_max of a symmetric positive definite a (p x p), certified to EIGENVALUE_TOLERANCE.

    Warm-started subspace iteration on two vectors: v (2, p) holds an
    orthonormal basis close to the top two eigenvectors from the previous
    call (updated in place). The larger Ritz value r of a on span(v) never
    exceeds lambda_max; r is accepted once (r (1 + tol)) I - a is positive
    definite (its Cholesky factorisation succeeds), which proves
    lambda_max < r (1 + tol); it is tried once r has settled (changed by
    less than tol / 10 in the last step). Two vectors make a pair of close top
    eigenvalues (DIARC's dN1, dN2 start equal) converge at once. If no
    certificate comes within ``iterations`` steps (e.g. after eigenvalues
    crossed), the exact :func:`largest_eigenvalue_exact` is used and v
    restarted. Gamma changes little per 0.2 ms sample, so one step usually
    suffices. w (2, p), t (p, p), diag, off (p,): scratch.
    """
    p = a.shape[0]
    previous = -math.inf
    for _ in range(iterations):
        # w = a v (two rows); h = v a v^T (2 x 2); r = its larger eigenvalue.
        h00 = 0.0
        h01 = 0.0
        h11 = 0.0
        for i in range(p):
            acc0 = 0.0
            acc1 = 0.0
            for k in range(p):
                acc0 += a[i, k] * v[0, k]
                acc1 += a[i, k] * v[1, k]
            w[0, i] = acc0
            w[1, i] = acc1
            h00 += v[0, i] * acc0
            h01 += v[0, i] * acc1
            h11 += v[1, i] * acc1
        mean = 0.5 * (h00 + h11)
        half_gap = 0.5 * (h00 - h11)
        rayleigh = mean + math.sqrt(half_gap * half_gap + h01 * h01)
        if not _orthonormalise(w, v):
            break
        # Try the (costlier) certificate only once the Ritz value has settled.
        settled = rayleigh - previous <= 0.1 * EIGENVALUE_TOLERANCE * rayleigh
        previous = rayleigh
        if not settled:
            continue
        shift = rayleigh * (1.0 + EIGENVALUE_TOLERANCE)
        for i in range(p):
            for k in range(i + 1):
                t[i, k] = -a[i, k]
            t[i, i] += shift
        if cholesky_factor(t, p, t):
            return rayleigh
    lam_max = largest_eigenvalue_exact(a, upper_bound, t, diag, off)
    # Restart the warm basis with vectors that cannot be orthogonal to the top eigenvectors
    # in general position, then let a few subspace steps pull it in.
    for i in range(p):
        v[0, i] = 1.0 / math.sqrt(p)
        v[1, i] = (1.0 if i % 2 == 0 else -1.0) / math.sqrt(p) + 1e-3 * i
    for r in range(2):
        for i in range(p):
            w[r, i] = v[r, i]
    _orthonormalise(w, v)
    for _ in range(30):
        for r in range(2):
            for i in range(p):
                acc = 0.0
                for k in range(p):
                    acc += a[i, k] * v[r, k]
                w[r, i] = acc
        _orthonormalise(w, v)
    return lam_max
