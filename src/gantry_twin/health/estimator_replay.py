"""DIARC's indirect estimator over recorded samples, one compiled loop (used by :mod:`gantry_twin.health.log_monitor`).

A module of its own: a kernel's module and the modules it imports key the
compiled cache (:func:`gantry_twin._jit.cache_dir`), so this one imports
only the estimator's kernels.
"""

from __future__ import annotations

from gantry_twin._jit import kernel
from gantry_twin.controllers.estimator import estimator_start, estimator_update


@kernel  # with reference counting: a row of theta_out takes a whole array (numba lowers that through NRT)
def estimator_replay(params, theta, est, q_m, dq_m_s, u_v, theta_out):  # pragma: no cover
    """DIARC's estimator over a log: q_m, dq_m_s, u_v (n, 2); theta^ after each sample into theta_out (n, 8)."""
    estimator_start(params, est, q_m[0], dq_m_s[0], u_v[0])
    theta_out[0] = theta
    for k in range(1, q_m.shape[0]):
        estimator_update(params, theta, est, q_m[k], dq_m_s[k], u_v[k - 1])
        theta_out[k] = theta
