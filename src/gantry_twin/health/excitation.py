"""How well a run excites the parameters of each axis (eq. 29), and how far its regressor errors can bias them.

From what the controller measured (``q_meas_m``, its backward difference, the constant) with DIARC's own
exact discretised filters Hf (:class:`FilteredRegressors`): per axis the information of eq. (25)'s regressor
over ``window_s``, normalised by the nominal values into volts (``level_v`` per axis, ``parameter_v`` per
parameter). Only sliding samples count, and none the reversal gate leaves out. :func:`estimate_bias`
predicts the bias from encoder quantisation (:func:`quantisation_noise`) and from the friction column's
error against sign(v). An estimate is trustworthy when excited, its axis sliding and that bias within
``max_bias``; :class:`gantry_twin.health.monitor.MachineMonitor` runs this over a sliding window.

(docs/health.md, "Excitation monitor" and "Regressor errors"; the equations: docs/equations.md, section 11)
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from gantry_twin.numerics.estimation import (
    FRICTION_SLOPE_S_M,
    PAPER_FILTER_HZ,
    PAPER_FILTER_ZETA,
    FilterHz,
    FilterZeta,
    FrictionSlope,
    discretise_filter,
    filter_axis,
    filter_steady_state,
    friction_shape,
)
from gantry_twin.numerics.jit import kernel
from gantry_twin.plant.sensing import ENCODER_RESOLUTION_M
from gantry_twin.settings import (
    VOLTS_MAX_V,
    NonNegative,
    Positive,
    Range,
    Vector,
    rule,
    validated,
)
from gantry_twin.theta import NOMINAL_THETA, THETA_NAMES

#: The friction column's error has a known sign only where no velocity reversal is in the filter's memory:
#: |Hf[s]| at least this, s the held sign of motion (the recommended estimator's reversal gate). Elsewhere
#: (stick, a run of zero differences across the reversal) only its size is known.
SIGN_KNOWN = 0.99
#: Parameter j belongs to axis AXIS_OF[j] and is column COLUMN_OF[j] of that axis' 4x4 block.
AXIS_OF = np.array([0, 1, 0, 1, 0, 1, 0, 1])
COLUMN_OF = np.array([0, 0, 1, 1, 2, 2, 3, 3])


class FilterSettings(Protocol):
    """What :class:`FilteredRegressors` needs (e.g. a :class:`gantry_twin.health.monitor.ExcitationSettings`)."""

    filter_hz: tuple[float, float]  # Hf per axis, Hz
    filter_zeta: float
    friction_slope_s_m: float  # the 9000 of Sf(v) = (2/pi) atan(9000 v)
    reversal_gate: float  # samples with |Sf_f| below this give a zero regressor (0: none)


@kernel(nrt=False)
def accumulate_information(g, weight, first_index, period, acc, moving, blocks, block_moving):  # pragma: no cover
    """Add weight_k g_k g_k^T (g (n, 2, p)) into per-period sums, sample by sample.

    acc (2, p, p), moving (2,) hold the open period; every closed period is
    written to blocks[m], block_moving[m]. Returns the number of closed periods.
    Element by element, no whole-array assignment or arithmetic: numba's code
    for those (broadcasting, a temporary array) took ten times the compile of
    the rest (docs/performance.md, "Compile").
    """
    m = 0
    p = g.shape[2]
    for k in range(g.shape[0]):
        for a in range(2):
            w = weight[k, a]
            if w != 0.0:
                moving[a] += 1.0
                for i in range(p):
                    for j in range(p):
                        acc[a, i, j] += w * g[k, a, i] * g[k, a, j]
        if (first_index + k + 1) % period == 0:
            for a in range(2):
                for i in range(p):
                    for j in range(p):
                        blocks[m, a, i, j] = acc[a, i, j]
                        acc[a, i, j] = 0.0
                block_moving[m, a] = moving[a] / period
                moving[a] = 0.0
            m += 1
    return m


class FilteredRegressors:
    """gamma_f per axis from measured positions, exactly as DIARC's estimator filters them.

    Sample k >= 2 gives g_k (2, 4) = [x_f'', x_f', Sf_f(x'), -1_f] per axis;
    the filters start in steady state at sample 1 (the first with a
    backward-difference velocity), as the estimator starts at its first sample.
    The velocity is always the backward difference of the positions given:
    a controller fed another velocity (ideal sensing without difference,
    velocity noise) filtered a slightly different Sf(x'). A sample whose
    |Sf_f| is below the settings' ``reversal_gate`` has g = 0 on that axis,
    as in the estimator. Given the commands, :attr:`u_f` (n, 2) is the
    estimator's target u_f (the previous sample's command, held, through Hf).
    The friction column's error against the plant's sign(v), at the samples
    of the last :meth:`advance`: :attr:`friction_error` (n, 2) =
    Hf[s (1 - |Sf(x')|)] (s: the sign of the last nonzero differenced
    velocity, held through zero differences) where its sign is known
    (|Hf[s]| >= SIGN_KNOWN), else 0; :attr:`reversal_error` (n, 2) =
    Hf[1 - |Sf(x')|], its size, where it is not, else 0.
    """

    def __init__(self, settings: FilterSettings, sample_period_s: float) -> None:
        self.ts = sample_period_s
        self.slope = settings.friction_slope_s_m
        self.gate = settings.reversal_gate
        self.discs = [
            discretise_filter(2.0 * np.pi * hz, settings.filter_zeta, sample_period_s) for hz in settings.filter_hz
        ]
        # axis, state [w_f, w_f'], signal: q, Sf, 1, u (DIARC's estimator's columns), s (1 - |Sf|), 1 - |Sf|, s
        self.z = np.zeros((2, 2, 7))
        self.friction_error = np.zeros((0, 2))
        self.reversal_error = np.zeros((0, 2))
        self.u_f = np.zeros((0, 2))
        self.previous_q = np.zeros(2)
        self.previous_u = np.zeros(2)
        self.sign = np.zeros(2)  # of the last nonzero differenced velocity, per axis
        self.seen = 0

    def advance(self, q_meas_m: np.ndarray, u_v: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Feed the next samples (n, 2) (and their commands u_v (n, 2), V); return (g (n, 2, 4), |x_f'| (n, 2)),
        zero before sample 2."""
        q = np.asarray(q_meas_m, dtype=float)
        n = q.shape[0]
        u = np.zeros((n, 2)) if u_v is None else np.asarray(u_v, dtype=float)
        g = np.zeros((n, 2, 4))
        speed = np.zeros((n, 2))
        prev = np.vstack([self.previous_q[None, :], q[:-1]])
        held_u = np.vstack([self.previous_u[None, :], u[:-1]])  # the estimator filters the previous command
        velocity = (q - prev) / self.ts
        skip = 0
        while self.seen + skip < 2 and skip < n:
            if self.seen + skip == 1:  # steady state for sample 1's inputs
                self._start(q[skip], velocity[skip], held_u[skip])
            skip += 1
        self.friction_error = np.zeros((n, 2))
        self.reversal_error = np.zeros((n, 2))
        self.u_f = np.zeros((n, 2))
        if skip < n:
            g[skip:], speed[skip:] = self._regressors(q[skip:], prev[skip:], velocity[skip:], held_u[skip:])
        self.seen += n
        if n:
            self.previous_q = q[-1].copy()
            self.previous_u = u[-1].copy()
        return g, speed

    def _start(self, q: np.ndarray, v: np.ndarray, u: np.ndarray) -> None:
        sf = friction_shape(v, self.slope)
        self.sign = np.where(v != 0.0, np.sign(v), self.sign)
        for axis, disc in enumerate(self.discs):
            deficit = 1.0 - abs(sf[axis])
            held = (sf[axis], 1.0, u[axis], self.sign[axis] * deficit, deficit, self.sign[axis])
            self.z[axis] = filter_steady_state(disc, q[axis], v[axis], held)

    def _regressors(self, q, prev, velocity, held_u) -> tuple[np.ndarray, np.ndarray]:
        """The one place the estimator's filter functions are used (docs/equations.md, the estimator's filters)."""
        n = q.shape[0]
        g = np.empty((n, 2, 4))
        sf = friction_shape(velocity, self.slope)
        deficit = 1.0 - np.abs(sf)
        sign = self._held_sign(velocity)
        error = sign * deficit
        known = np.empty((n, 2), dtype=bool)
        for axis, disc in enumerate(self.discs):
            held = np.stack(
                [sf[:, axis], np.ones(n), held_u[:, axis], error[:, axis], deficit[:, axis], sign[:, axis]], 1
            )
            acc, vel, filtered = filter_axis(self.z[axis], disc, q[:, axis], prev[:, axis], held, self.ts)
            g[:, axis, 0] = acc
            g[:, axis, 1] = vel
            g[:, axis, 2] = filtered[:, 0]
            g[:, axis, 3] = -filtered[:, 1]
            self.u_f[-n:, axis] = filtered[:, 2]
            self.friction_error[-n:, axis] = filtered[:, 3]
            self.reversal_error[-n:, axis] = filtered[:, 4]
            known[:, axis] = np.abs(filtered[:, 5]) >= SIGN_KNOWN
        self.friction_error[-n:][~known] = 0.0
        self.reversal_error[-n:][known] = 0.0
        speed = np.abs(g[:, :, 1])
        gated = np.abs(g[:, :, 2]) < self.gate
        g[gated] = 0.0
        self.u_f[-n:][gated] = 0.0  # as the estimator's: a gated row is no equation
        return g, speed

    def _held_sign(self, velocity: np.ndarray) -> np.ndarray:
        """sign(v) per sample (n, 2), a zero difference taking the last nonzero one's (the plant still slides)."""
        sign = np.sign(velocity)
        rows = np.arange(len(sign))[:, None]
        last = np.maximum.accumulate(np.where(sign != 0.0, rows, -1), axis=0)
        held = np.where(last >= 0, sign[np.maximum(last, 0), np.arange(2)], self.sign)
        if len(sign):
            self.sign = held[-1].copy()
        return held


def quantisation_noise(settings: FilterSettings, resolution_m: float, sample_period_s: float) -> np.ndarray:
    """rms noise (2 axes, 2) of [x_f'' m/s^2, x_f' m/s] from encoder quantisation: white, variance r^2 / 12.

    The sum of squares of the discrete filter's impulse response from the
    position samples (first-order hold) to each output, times r^2 / 12.
    """
    out = np.zeros((2, 2))
    for axis, hz in enumerate(settings.filter_hz):
        disc = discretise_filter(2.0 * np.pi * hz, settings.filter_zeta, sample_period_s)
        n = int(40.0 / (disc.zeta * disc.wn_rad_s * sample_period_s)) + 2  # 40 time constants: e^-40 left
        q = np.zeros(n)
        q[1] = 1.0
        previous = np.concatenate([[0.0], q[:-1]])
        acceleration, velocity, _ = filter_axis(np.zeros((2, 1)), disc, q, previous, np.zeros((n, 0)), sample_period_s)
        out[axis] = np.sqrt(resolution_m**2 / 12.0 * np.array([np.sum(acceleration**2), np.sum(velocity**2)]))
    return out


def estimate_bias(
    parameter_v: np.ndarray,
    scale: np.ndarray,
    noise: np.ndarray,
    information: np.ndarray,
    moment: np.ndarray,
    correlated: bool = False,
) -> np.ndarray:
    """The relative bias (..., 8) of each estimate from its regressor errors (docs/health.md, "Regressor errors").

    parameter_v (..., 8) V; scale (8,) nominal values; noise (2, 2): rms of
    [x_f'', x_f'] per axis (:func:`quantisation_noise`); information
    (..., 2, 4, 4): sum g g^T dt; moment (..., 2, 2, 4): [sum g e dt, sum |g| d dt]
    over the same samples (:func:`accumulate_moment`). Errors in variables:
    with ``correlated``, |I^-1 W diag(sigma^2) theta| / scale (W: the
    constant column's information, sum 1_f^2 dt, the seconds used;
    theta = scale), otherwise only each column's own share,
    (scale sigma / parameter_v)^2 (the monitor's, whose tests and 0.01 V floor
    were set with it); plus the friction column's
    Af (|I^-1 m_e| + |I^-1| m_d) / scale; infinite without information.
    """
    nominal = np.stack([scale[0::2], scale[1::2]])  # (axis, column)
    noise_energy = np.zeros((*information.shape[:-2], 4))
    noise_energy[..., :2] = noise**2 * information[..., 3, 3, None]  # x_f'', x_f' columns
    eps = 1e-12 * np.trace(information, axis1=-2, axis2=-1)[..., None, None] + 1e-300
    inverse = np.linalg.inv(information + eps * np.eye(4))
    variables = np.abs(np.einsum("...ij,...j->...i", inverse, noise_energy * nominal))
    if not correlated:
        own = np.zeros((2, 4))
        own[:, :2] = nominal[:, :2] * noise  # noise_v of M, B per axis
        with np.errstate(divide="ignore", invalid="ignore"):
            variables = nominal * (own[AXIS_OF, COLUMN_OF] / parameter_v)[..., [[0, 2, 4, 6], [1, 3, 5, 7]]] ** 2
    signed = np.abs(np.einsum("...ij,...j->...i", inverse, moment[..., 0, :, :]))
    unsigned = np.einsum("...ij,...j->...i", np.abs(inverse), moment[..., 1, :, :])
    friction = nominal[:, 2, None]  # Af per axis
    bias = ((variables + friction * (signed + unsigned)) / nominal)[..., AXIS_OF, COLUMN_OF]
    return np.where(parameter_v > 0.0, bias, np.inf)


@kernel(nrt=False)
def accumulate_moment(g, error, size, weight, first_index, period, acc, blocks):  # pragma: no cover
    """Add weight_k g_k error_k into acc[0] and weight_k |g_k| size_k into acc[1] (g (n, 2, 4); error, size
    (n, 2): the friction column's signed error and, where its sign is unknown, its size; acc (2, 2, 4)), as
    :func:`accumulate_information` does; each closed period into blocks[m]. Returns the number closed."""
    m = 0
    for k in range(g.shape[0]):
        for a in range(2):
            w = weight[k, a] * error[k, a]
            u = weight[k, a] * abs(size[k, a])
            for i in range(4):
                acc[0, a, i] += w * g[k, a, i]
                acc[1, a, i] += u * abs(g[k, a, i])
        if (first_index + k + 1) % period == 0:
            for j in range(2):
                for a in range(2):
                    for i in range(4):
                        blocks[m, j, a, i] = acc[j, a, i]
                        acc[j, a, i] = 0.0
            m += 1
    return m


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


#: The monitor's settings that a scenario file also sets (its ``monitor`` mapping).
ExcitationWindowS = Range(0.01, 600.0, "s")
MinParameterV = Range(0.0, VOLTS_MAX_V, "V")


#: The volt scale of dN1, dN2 in the excitation's normalisation (their nominal value is 0).
DN_SCALE_V = 0.1


@validated("excitation")
class ExcitationSettings:
    """How the information of eq. (29) is measured.

    window_s: sliding window W, s (2 s holds a velocity reversal of each axis on
    the paper's circle and ellipse, needed to separate Af from dN).
    period_s: monitor period, s: outputs (and health decisions) every period.
    filter_hz, filter_zeta: Hf per axis; use the estimator's (paper: 250/150 Hz).
    friction_slope_s_m: the 9000 of Sf(v) = (2/pi) atan(9000 v); reversal_gate: the
    estimator's (samples it leaves out near a velocity reversal carry no information).
    resolution_m: the encoder's (0: ideal), for the quantisation noise in x_f'', x_f'.
    sliding_speed_m_s: samples with |x_f'| below this carry no information.
    scale: nominal parameter values D (volt units; dN: a volt scale), for the
    normalisation N = D I D / W.
    min_parameter_v: a parameter is excited when its ``parameter_v`` reaches this.
    min_moving_fraction: ... and its axis slid in this fraction of the latest period.
    max_bias: ... and the bound of the relative bias from its regressor errors is at most this
    (otherwise it is excited but untrustworthy).
    max_error: an estimate in summary.json is trustworthy when that bound plus its gap to the
    least-squares fit is at most this (:mod:`gantry_twin.health.confidence`).
    """

    window_s: ExcitationWindowS = 2.0
    period_s: Range(0.0, 1.0, "s", lo_open=True) = 0.01
    filter_hz: FilterHz = PAPER_FILTER_HZ
    filter_zeta: FilterZeta = PAPER_FILTER_ZETA
    friction_slope_s_m: FrictionSlope = FRICTION_SLOPE_S_M
    reversal_gate: Range(0.0, 1.0) = 0.0
    resolution_m: Range(0.0, 1.0e-3, "m") = ENCODER_RESOLUTION_M
    sliding_speed_m_s: NonNegative = 1.0e-3
    scale: Vector(Positive, THETA_NAMES) = (*NOMINAL_THETA[:6], DN_SCALE_V, DN_SCALE_V)
    min_parameter_v: MinParameterV = 0.01
    min_moving_fraction: Range(0.0, 1.0) = 0.5
    #: 2 %: a fifth of the health tolerance (10 %), so that a trusted estimate's bias cannot read as a drift.
    max_bias: Range(0.0, 1.0) = 0.02
    #: 4 %: the 5 % accuracy target less a margin for what the bound leaves out (docs/estimator-envelope.md).
    max_error: Range(0.0, 1.0) = 0.04

    def __post_init__(self) -> None:
        if self.window_s < self.period_s:
            raise rule("window_s", f"must be at least period_s = {self.period_s:g} s, got {self.window_s:g}")
