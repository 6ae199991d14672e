"""DIARC's indirect estimator (paper section 4.2): its settings, the filtered regression of eq. (25) per
sample and the least squares of eq. (27-28), as kernels the controller's step calls (docs/equations.md,
"The estimator")."""

from __future__ import annotations

from dataclasses import field
from typing import NamedTuple

import numpy as np

from gantry_twin.controllers.law import ArcGains
from gantry_twin.numerics.estimation import (
    PAPER_FILTER_HZ,
    PAPER_FILTER_ZETA,
    FilterDiscretisation,
    FilterHz,
    FilterZeta,
    FrictionSlope,
    LeastSquaresSettings,
    LeastSquaresWork,
    discretise_filter,
    filter_advance,
    filter_start,
    filtered_acceleration,
    friction_shape,
    least_squares_update,
    least_squares_work,
)
from gantry_twin.numerics.jit import kernel
from gantry_twin.plant.model import AXES
from gantry_twin.settings import VOLTS_MAX_V, OrNamed, Range, Vector, validated

#: Entries of EstimatorState.clock.
CLOCK_TIME_S, CLOCK_STARTED, CLOCK_LAMBDA_MAX = 0, 1, 2


@validated("estimator")
class EstimatorSettings:
    """DIARC's indirect estimator and fast compensation (paper section 5).

    filter_hz: natural frequencies of Hf for X, Y (paper: 250, 150 Hz).
    filter_zeta: damping ratio of Hf (paper: 0.7).
    least_squares: nu, kappa, rho_M, Gamma(0) of eq. (27)-(28).
    gamma_d: dc^ adaptation rates, V/(m/s)/s... (paper: 1e4, 1e4).
    dc_max_v: dc^ bounds (paper: 0.5, 1.5 V).
    settle_s: the estimator waits this long after the start for its filters'
    initial transient to die out (the filters start in steady state for the
    first sample's inputs, so this is only a precaution).
    """

    filter_hz: FilterHz = PAPER_FILTER_HZ
    filter_zeta: FilterZeta = PAPER_FILTER_ZETA
    least_squares: LeastSquaresSettings = field(default_factory=LeastSquaresSettings)
    #: dc^ rate: at most 1e6, where a 5 mm/s sliding error moves dc^ by 1 V in one sample (a relay).
    gamma_d: Vector(Range(0.0, 1.0e6), AXES) = (1.0e4, 1.0e4)
    #: |dc^| bound: within the DAC's +-10 V.
    dc_max_v: Vector(Range(0.0, VOLTS_MAX_V, "V"), AXES) = (0.5, 1.5)
    #: At most 10 s: a few time constants 1 / (zeta wn) of the slowest allowed filter (5 Hz, zeta 0.1).
    settle_s: Range(0.0, 10.0, "s") = 0.02
    #: The slope of Sf(v) in the estimator's friction regressor, s/m; None: the controller's (paper: 9000). Far
    #: above 1 / (the velocity step by difference, 2.5 mm/s) Sf is sign(v): the plant's Coulomb friction.
    friction_slope_s_m: FrictionSlope | None = None
    #: An axis' sample is left out of the least squares while its filtered friction regressor |Sf_f| < this:
    #: a velocity reversal (stick, a differenced velocity of 0) is still in the filter's memory. 0: never (paper).
    reversal_gate: Range(0.0, 1.0) = 0.0


#: The twin's recommended estimator: 10 Hz filters, which keep the encoder's 0.5 um quantisation noise out of x_f''
#: (docs/equations.md, the estimator's filters) also on slow contours; the friction regressor sign(v) of the differenced
#: velocity (Sf with slope 1e6 s/m), with samples near a velocity reversal left out (reversal_gate 0.99): the smooth Sf
#: and the dither of a differenced velocity below its 2.5 mm/s step bias B and M on slow contours; forgetting
#: kappa = 0.7 1/s (paper: 0.1), a memory of about 1.4 s, so that the estimates follow a changing machine (a payload
#: pick-up, a friction drift) within the health monitor's targets; nu = 0.01 and rho_M = 1e4 (paper: 0.1, 500), so that
#: B, whose regressor is the small velocity of a slow contour, still converges within that memory instead of being
#: starved by the normalisation n; and a faster dc^ rate gamma_d = 3e4 (paper: 1e4), so that dc^ follows cogging ripple.
#: The measurements behind each choice are in docs/health.md ("The recommended estimator") and
#: docs/estimator-envelope.md.
RECOMMENDED_ESTIMATOR = EstimatorSettings(
    filter_hz=(10.0, 10.0),
    least_squares=LeastSquaresSettings(kappa=0.7, nu=0.01, rho_max=1.0e4),
    gamma_d=(3.0e4, 3.0e4),
    friction_slope_s_m=1.0e6,
    reversal_gate=0.99,
)
#: The estimators a scenario file may name instead of spelling them out.
NAMED_ESTIMATORS = {"paper": EstimatorSettings(), "recommended": RECOMMENDED_ESTIMATOR}
#: EstimatorSettings, or in a scenario file one of NAMED_ESTIMATORS by name.
EstimatorChoice = OrNamed(EstimatorSettings, NAMED_ESTIMATORS)


class EstimatorParams(NamedTuple):
    """DIARC's estimator settings as arrays (per axis X, Y).

    filter_phi (2, 2, 2), filter_hold (2, 2), filter_ramp (2, 2): the exact
    discretisation of Hf per axis; filter_wn_rad_s, filter_zeta (2,);
    nu, kappa, rho_max: eq. (27)-(28); settle_s, friction_slope_s_m (resolved: never None),
    reversal_gate: see EstimatorSettings.
    """

    filter_phi: np.ndarray
    filter_hold: np.ndarray
    filter_ramp: np.ndarray
    filter_wn_rad_s: np.ndarray
    filter_zeta: np.ndarray
    nu: float
    kappa: float
    rho_max: float
    settle_s: float
    friction_slope_s_m: float
    reversal_gate: float


class EstimatorState(NamedTuple):
    """DIARC's estimator state, owned by :class:`IndirectEstimator`.

    gamma (8, 8): the adaptation gain Gamma; z (2, 2, 4): filter states per
    axis, rows [w_f, w_f'], columns [q, Sf, 1, u]; previous_q_m (2,);
    clock (3,): [time since start s, started 0/1, lambda_max(Gamma)];
    regression (8, 2) gamma_f and u_f (2,) of the last sample; work: scratch.
    """

    gamma: np.ndarray
    z: np.ndarray
    previous_q_m: np.ndarray
    clock: np.ndarray
    regression: np.ndarray
    u_f: np.ndarray
    work: LeastSquaresWork


@kernel(internal=True, nrt=False)
def estimator_start(params, est, q_m, dq_m_s, u_v):
    """Put each filter in steady state for the first sample's inputs."""
    wn, zeta = params.estimator.filter_wn_rad_s, params.estimator.filter_zeta
    z_all, previous_q_m, clock = est.z, est.previous_q_m, est.clock
    for axis in range(2):
        sf = friction_shape(dq_m_s[axis], params.estimator.friction_slope_s_m)
        z = z_all[axis]
        filter_start(z, wn[axis], zeta[axis], q_m[axis], dq_m_s[axis])
        z[0, 1], z[0, 2], z[0, 3] = sf, 1.0, u_v[axis]
        z[1, 1], z[1, 2], z[1, 3] = 0.0, 0.0, 0.0
        previous_q_m[axis] = q_m[axis]
    clock[CLOCK_STARTED] = 1.0


@kernel(inline=True, internal=True, nrt=False)
def estimator_regression(params, est, q_m, dq_m_s, u_previous_v):
    """Advance the filters to this sample (eq. 25); fill est.regression (gamma_f) and est.u_f.

    The position rises linearly from the previous sample (first-order hold);
    Sf(q'), the constant and the applied u are held (zero-order hold). An axis
    whose |Sf_f| is below the reversal gate gives a zero row (no information).
    """
    f_phi, f_hold, f_ramp, f_wn, f_zeta = params.estimator[:5]
    z_all, previous_q_m, g, u_f = est.z, est.previous_q_m, est.regression, est.u_f
    ts = params.sample_period_s
    for axis in range(2):
        z = z_all[axis]
        phi, hold, ramp = f_phi[axis], f_hold[axis], f_ramp[axis]
        sf = friction_shape(dq_m_s[axis], params.estimator.friction_slope_s_m)
        q_previous = previous_q_m[axis]
        filter_advance(z, 0, phi, hold, ramp, q_previous, (q_m[axis] - q_previous) / ts)
        filter_advance(z, 1, phi, hold, ramp, sf, 0.0)
        filter_advance(z, 2, phi, hold, ramp, 1.0, 0.0)
        filter_advance(z, 3, phi, hold, ramp, u_previous_v[axis], 0.0)
        g[axis, axis] = filtered_acceleration(z[0, 0], z[1, 0], f_wn[axis], f_zeta[axis], q_m[axis])
        g[2 + axis, axis] = z[1, 0]
        g[4 + axis, axis] = z[0, 1]
        g[6 + axis, axis] = -z[0, 2]
        u_f[axis] = z[0, 3]
        previous_q_m[axis] = q_m[axis]
        if abs(z[0, 1]) < params.estimator.reversal_gate:  # a reversal in the filter's memory: no information
            for j in range(8):
                g[j, axis] = 0.0
            u_f[axis] = 0.0


@kernel(inline=True, internal=True, nrt=False)
def estimator_update(params, theta, est, q_m, dq_m_s, u_previous_v):
    """One sample of the indirect estimator: filter, then least squares on theta (in place)."""
    estimator_regression(params, est, q_m, dq_m_s, u_previous_v)
    clock = est.clock
    clock[CLOCK_TIME_S] += params.sample_period_s
    ep = params.estimator
    if clock[CLOCK_TIME_S] < ep.settle_s:
        return
    clock[CLOCK_LAMBDA_MAX] = least_squares_update(
        theta,
        est.gamma,
        est.regression,
        est.u_f,
        ep.nu,
        ep.kappa,
        ep.rho_max,
        params.lower,
        params.upper,
        params.sample_period_s,
        est.work,
    )


class IndirectEstimator:
    """Filtered regression (eq. 25) and least squares (eq. 27-28) for both axes.

    Per axis, four signals pass through the same Hf: the measured position
    (first-order hold: it moves continuously between samples), Sf(q'), the
    constant 1 and the applied input u (zero-order hold: the DAC holds u and
    the measured velocity is the mean over the last sample). Filter states are
    ``z[axis]`` of shape (2, 4): rows [w_f, w_f'], columns [q, Sf, 1, u].
    The arrays live in :attr:`state` (:class:`EstimatorState`).
    """

    def __init__(self, settings: EstimatorSettings, gains: ArcGains, sample_period_s: float) -> None:
        self.settings = settings
        self.gains = gains
        self.sample_period_s = sample_period_s
        self.filters: list[FilterDiscretisation] = [
            discretise_filter(2.0 * np.pi * hz, settings.filter_zeta, sample_period_s) for hz in settings.filter_hz
        ]
        ls = settings.least_squares
        self.params = EstimatorParams(
            np.array([f.phi for f in self.filters]),
            np.array([f.hold for f in self.filters]),
            np.array([f.ramp for f in self.filters]),
            np.array([f.wn_rad_s for f in self.filters], dtype=float),
            np.array([f.zeta for f in self.filters], dtype=float),
            float(ls.nu),
            float(ls.kappa),
            float(ls.rho_max),
            float(settings.settle_s),
            float(gains.friction_slope_s_m if settings.friction_slope_s_m is None else settings.friction_slope_s_m),
            float(settings.reversal_gate),
        )
        gamma = np.diag(np.asarray(ls.gamma0_diag, dtype=float))
        clock = np.array([0.0, 0.0, float(np.max(ls.gamma0_diag))])
        self.state = EstimatorState(
            gamma,
            np.zeros((2, 2, 4)),
            np.zeros(2),
            clock,
            np.zeros((8, 2)),
            np.zeros(2),
            least_squares_work(8, 2, gamma),
        )

    @property
    def gamma(self) -> np.ndarray:
        """Gamma (8, 8), the adaptation gain (the state array itself)."""
        return self.state.gamma

    @property
    def lambda_max(self) -> float:
        """lambda_max(Gamma) after the last update."""
        return float(self.state.clock[CLOCK_LAMBDA_MAX])


def placeholder_estimator() -> EstimatorParams:
    """Estimator settings for DRC and DARC, which have no estimator (never read)."""
    z2 = np.ones(2)
    return EstimatorParams(
        np.zeros((2, 2, 2)), np.zeros((2, 2)), np.zeros((2, 2)), z2, z2, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
    )
