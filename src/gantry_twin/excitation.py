"""How well a run excites the parameters of each axis (eq. 29), from what the controller measured.

Per axis i the regressor of eq. (25) is
g_i = [x_f'', x_f', Sf_f(x'), -1_f] (the axis' columns M_i, B_i, Af_i, dN_i),
computed from what the controller measured: the encoder positions
``q_meas_m`` (first-order hold into Hf), the backward-difference velocity
through Sf, and the constant, with the same exact discretised filters Hf as
DIARC's estimator (:class:`FilteredRegressors`). The information over the
last ``window_s`` seconds, I_i = int g_i g_i^T dt (eq. 29), is normalised by
the nominal parameter values D = diag(scale) and the window length W
(``window_s``, ``scale``: :class:`gantry_twin.monitor.ExcitationSettings`):

    N_i = D I_i D / W        (volts^2)

so a relative parameter change delta (delta = 1 is +100 %) moves the filtered
input by sqrt(delta^T N_i delta) volts rms over the window. Reported:

* ``level_v`` (per axis): sqrt(lambda_min(N_i)), the rms signature of a
  100 % change in the least excited direction (PE condition (29) in volts);
* ``parameter_v`` (per parameter): sqrt(1 / (N_i^-1)_jj), the rms signature
  of a 100 % change of parameter j that the axis' other three parameters
  cannot mimic (its conditional information, the Cramer-Rao view).

Model (25) holds only while the axis slides: in stick, Coulomb friction is
any force up to Af, not Af Sf(v). Samples with |x_f'| below
``sliding_speed_m_s`` therefore add nothing to I_i. At standstill every
parameter, dN included, has zero information.

:class:`gantry_twin.monitor.MachineMonitor` runs this over a sliding window
and judges the estimates only where it finds enough excitation.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from gantry_twin._jit import kernel
from gantry_twin.estimation import (
    FilterDiscretisation,
    discretise_filter,
    filter_run,
    filtered_acceleration,
    friction_shape,
)

#: Parameter j belongs to axis AXIS_OF[j] and is column COLUMN_OF[j] of that axis' 4x4 block.
AXIS_OF = np.array([0, 1, 0, 1, 0, 1, 0, 1])
COLUMN_OF = np.array([0, 0, 1, 1, 2, 2, 3, 3])


class FilterSettings(Protocol):
    """What :class:`FilteredRegressors` needs (e.g. a :class:`gantry_twin.monitor.ExcitationSettings`)."""

    filter_hz: tuple[float, float]  # Hf per axis, Hz
    filter_zeta: float
    friction_slope_s_m: float  # the 9000 of Sf(v) = (2/pi) atan(9000 v)


@kernel
def accumulate_information(g, weight, first_index, period, acc, moving, blocks, block_moving):  # pragma: no cover
    """Add weight_k g_k g_k^T (g (n, 2, 4)) into per-period sums, sample by sample.

    acc (2, 4, 4), moving (2,) hold the open period; every closed period is
    written to blocks[m], block_moving[m]. Returns the number of closed periods.
    """
    m = 0
    for k in range(g.shape[0]):
        for a in range(2):
            w = weight[k, a]
            if w != 0.0:
                moving[a] += 1.0
                for i in range(4):
                    for j in range(4):
                        acc[a, i, j] += w * g[k, a, i] * g[k, a, j]
        if (first_index + k + 1) % period == 0:
            blocks[m] = acc
            block_moving[m] = moving / period
            acc[:] = 0.0
            moving[:] = 0.0
            m += 1
    return m


class FilteredRegressors:
    """gamma_f per axis from measured positions, exactly as DIARC's estimator filters them.

    Sample k >= 2 gives g_k (2, 4) = [x_f'', x_f', Sf_f(x'), -1_f] per axis;
    the filters start in steady state at sample 1 (the first with a
    backward-difference velocity), as the estimator starts at its first sample.
    The velocity is always the backward difference of the positions given:
    a controller fed another velocity (ideal sensing without difference,
    velocity noise) filtered a slightly different Sf(x').
    """

    def __init__(self, settings: FilterSettings, sample_period_s: float) -> None:
        self.ts = sample_period_s
        self.slope = settings.friction_slope_s_m
        self.discs = [
            discretise_filter(2.0 * np.pi * hz, settings.filter_zeta, sample_period_s) for hz in settings.filter_hz
        ]
        self.z = np.zeros((2, 2, 3))  # axis, state [w_f, w_f'], signal (q, Sf, 1)
        self.previous_q = np.zeros(2)
        self.seen = 0

    def advance(self, q_meas_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Feed the next samples (n, 2); return (g (n, 2, 4), |x_f'| (n, 2)), zero before sample 2."""
        q = np.asarray(q_meas_m, dtype=float)
        n = q.shape[0]
        g = np.zeros((n, 2, 4))
        speed = np.zeros((n, 2))
        prev = np.vstack([self.previous_q[None, :], q[:-1]])
        velocity = (q - prev) / self.ts
        skip = 0
        while self.seen + skip < 2 and skip < n:
            if self.seen + skip == 1:  # steady state for sample 1's inputs
                self._start(q[skip], velocity[skip])
            skip += 1
        if skip < n:
            g[skip:], speed[skip:] = self._regressors(q[skip:], prev[skip:], velocity[skip:])
        self.seen += n
        if n:
            self.previous_q = q[-1].copy()
        return g, speed

    def _start(self, q: np.ndarray, v: np.ndarray) -> None:
        sf = friction_shape(v, self.slope)
        for axis, disc in enumerate(self.discs):
            self.z[axis] = filter_steady_state(disc, q[axis], v[axis], (sf[axis], 1.0))

    def _regressors(self, q, prev, velocity) -> tuple[np.ndarray, np.ndarray]:
        """The one place the estimator's filter functions are used (control-spec section 7)."""
        n = q.shape[0]
        g = np.empty((n, 2, 4))
        sf = friction_shape(velocity, self.slope)
        for axis, disc in enumerate(self.discs):
            held = np.stack([sf[:, axis], np.ones(n)], axis=1)
            acc, vel, filtered = filter_axis(self.z[axis], disc, q[:, axis], prev[:, axis], held, self.ts)
            g[:, axis, 0] = acc
            g[:, axis, 1] = vel
            g[:, axis, 2] = filtered[:, 0]
            g[:, axis, 3] = -filtered[:, 1]
        return g, np.abs(g[:, :, 1])


def filter_steady_state(disc: FilterDiscretisation, q_m: float, v_m_s: float, held: Sequence[float]) -> np.ndarray:
    """Filter states (2, 1 + k) of one axis in steady state: the position moving at v, the k inputs held.

    Columns as :func:`filter_axis` keeps them: [q, held...]; rows [w_f, w_f'].
    """
    lag = 2.0 * disc.zeta / disc.wn_rad_s
    z = np.zeros((2, 1 + len(held)))
    z[:, 0] = (q_m - lag * v_m_s, v_m_s)
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


def normalised_excitation(info: np.ndarray, scale: np.ndarray, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(level_v (..., 2), parameter_v (..., 8)) from windowed information (..., 2, 4, 4).

    N = D I D / W per axis; level = sqrt(lambda_min N); parameter j:
    sqrt(1 / (N^-1)_jj) (its conditional information), computed on N + eps I
    with eps = 1e-12 tr N so that a singular block gives ~0, not an error.
    """
    d = np.stack([scale[0::2], scale[1::2]], axis=0)  # (axis, column)
    n = info * d[:, :, None] * d[:, None, :] / window_s
    level = np.sqrt(np.clip(np.linalg.eigvalsh(n)[..., 0], 0.0, None))
    eps = 1e-12 * np.trace(n, axis1=-2, axis2=-1)[..., None, None] + 1e-300
    inverse = np.linalg.inv(n + eps * np.eye(4))
    cond = 1.0 / np.diagonal(inverse, axis1=-2, axis2=-1)  # (..., 2 axes, 4 columns)
    parameter = np.sqrt(np.clip(cond, 0.0, None))[..., AXIS_OF, COLUMN_OF]
    return level, parameter
