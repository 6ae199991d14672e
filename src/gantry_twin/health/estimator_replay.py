"""DIARC's indirect estimator over recorded samples, one compiled loop (used by :mod:`gantry_twin.health.log_monitor`).

A module of its own: a kernel's module and the modules it imports key the
compiled cache (:func:`gantry_twin.numerics.jit.cache_dir`), so this one imports
only the estimator's kernels.
"""

from __future__ import annotations

from gantry_twin.controllers.estimator import estimator_start, estimator_update
from gantry_twin.numerics.jit import kernel


@kernel  # with reference counting: a row of theta_out takes a whole array (numba lowers that through NRT)
def estimator_replay(params, theta, est, q_m, dq_m_s, u_held, start, theta_out):  # pragma: no cover
    """DIARC's estimator over n samples of a log, a chunk at a time: q_m, dq_m_s (n, 2); u_held (n, 2) the command
    held over the interval before each sample (the previous sample's); theta^ after each sample into theta_out
    (n, 8). ``start``: the chunk is the log's first, its sample 0 starts the filters (u_held[0] = its command)."""
    first = 0
    if start:
        estimator_start(params, est, q_m[0], dq_m_s[0], u_held[0])
        theta_out[0] = theta
        first = 1
    for k in range(first, q_m.shape[0]):
        estimator_update(params, theta, est, q_m[k], dq_m_s[k], u_held[k])
        theta_out[k] = theta
