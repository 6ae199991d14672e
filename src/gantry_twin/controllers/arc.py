"""DRC (C3), DARC (C1) and DIARC (C2): one law, three sources of theta^.

All three apply :func:`gantry_twin.controllers.law.arc_law`; they differ only
in how theta^ (and for DIARC dc^) move after each sample:

* DRC: theta^ = theta0, fixed (paper C3, "Gamma = 0").
* DARC: gradient adaptation theta^' = Proj(-Gamma Phi^T s_c) with diagonal
  Gamma and the discontinuous projection of eq. (9).
* DIARC: theta^ from the indirect least-squares estimator of section 4.2
  (:class:`IndirectEstimator`) and the fast dynamic compensation
  dc^' = Proj(gamma_d s_c), |dc^| <= dcmax (eq. 21-22).

A controller's settings are an :class:`ArcParams` and its whole state an
:class:`ArcState` of float64 arrays, both built by ``reset``. One sample is
:func:`drc_step`, :func:`darc_step` or :func:`diarc_step`, numba kernels
around the shared :func:`_law`: ``update()`` runs the plain-Python
reference version, and each class offers the compiled one to the loop
through the plug-in protocol (``compiled``, ``kernel_arguments``; see
:mod:`gantry_twin.controllers.base`) like any other controller.

The module runs past 500 lines because the three controllers' settings,
state and steps share the law and DIARC's estimator kernels: splitting them
would put the paper's section 4 in two files.
"""

from __future__ import annotations

from dataclasses import field
from typing import NamedTuple

import numpy as np

from gantry_twin._jit import kernel
from gantry_twin._jit import reference as uncompiled
from gantry_twin.controllers.base import (
    U_MAX_V,
    CompiledStep,
    Measurement,
    ReferenceSample,
    RunContext,
    log_values,
)
from gantry_twin.controllers.law import ArcGains, LawWork, Theta, arc_law, law_work
from gantry_twin.estimation import (
    PAPER_FILTER_HZ,
    PAPER_FILTER_ZETA,
    FilterDiscretisation,
    FilterHz,
    FilterZeta,
    FrictionSlope,
    LeastSquaresSettings,
    LeastSquaresWork,
    clip,
    discretise_filter,
    filter_advance,
    filtered_acceleration,
    friction_shape,
    least_squares_update,
    least_squares_work,
    project_box,
)
from gantry_twin.plant import AXES, THETA_NAMES
from gantry_twin.settings import VOLTS_MAX_V, OrNamed, Range, Vector, validated

#: DARC's adaptation rates (paper section 5).
DARC_GAMMA = (10.0, 10.0, 10.0, 10.0, 1.0, 1.0, 10000.0, 10000.0)
#: Adaptation rates of theta^, one per parameter: at most 1e8, where one sample's step (Ts gamma = 2e4)
#: already crosses the whole theta box for a 0.1 mm/s sliding error: a relay, not an adaptation.
Rates = Vector(Range(0.0, 1.0e8), THETA_NAMES)

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


class ArcParams(NamedTuple):
    """Everything fixed during a run of DRC, DARC or DIARC (float64 arrays, SI/volts).

    lam (2,) 1/s and ks (2,)
    V/(m/s): diagonals of Lambda and Ks; lower, upper (8,): theta bounds;
    u_max_v (2,); darc_gamma (8,): DARC's rates; gamma_d (2,), dc_max_v (2,):
    DIARC's dc^ law; estimator: DIARC's (placeholders for the others).
    """

    sample_period_s: float
    lam: np.ndarray
    ks: np.ndarray
    friction_slope_s_m: float
    lower: np.ndarray
    upper: np.ndarray
    u_max_v: np.ndarray
    darc_gamma: np.ndarray
    gamma_d: np.ndarray
    dc_max_v: np.ndarray
    estimator: EstimatorParams


class ArcState(NamedTuple):
    """The controller's whole state: theta (8,), dc (2,) volts, the last command (2,) volts,
    the estimator's state and the law's per-sample work (its u_v is the command)."""

    theta: np.ndarray
    dc: np.ndarray
    u_previous_v: np.ndarray
    estimator: EstimatorState
    law: LawWork


@kernel(internal=True)
def estimator_start(params, est, q_m, dq_m_s, u_v):
    """Put each filter in steady state for the first sample's inputs."""
    wn, zeta = params.estimator.filter_wn_rad_s, params.estimator.filter_zeta
    z_all, previous_q_m, clock = est.z, est.previous_q_m, est.clock
    for axis in range(2):
        sf = friction_shape(dq_m_s[axis], params.estimator.friction_slope_s_m)
        lag = 2.0 * zeta[axis] / wn[axis]
        z = z_all[axis]
        z[0, 0], z[0, 1], z[0, 2], z[0, 3] = q_m[axis] - lag * dq_m_s[axis], sf, 1.0, u_v[axis]
        z[1, 0], z[1, 1], z[1, 2], z[1, 3] = dq_m_s[axis], 0.0, 0.0, 0.0
        previous_q_m[axis] = q_m[axis]
    clock[CLOCK_STARTED] = 1.0


@kernel(inline=True, internal=True)
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


@kernel(inline=True, internal=True)
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


@kernel(inline=True, internal=True)
def _law(params, state, q_m, dq_m_s, ref, u_v):
    """The shared law (eq. 13-14, 17, 21) with this controller's theta^ and dc^; the command into u_v (2,) V."""
    law = state.law
    arc_law(
        q_m, dq_m_s, ref, state.theta, state.dc, params.lam, params.ks, params.friction_slope_s_m, params.u_max_v, law
    )
    u_v[0] = law.u_v[0]
    u_v[1] = law.u_v[1]


@kernel
def drc_step(params, state, t_s, q_m, dq_m_s, ref, u_v):
    """One 0.2 ms sample of DRC: the law with theta^ fixed; the command (volts) into u_v (2,)."""
    _law(params, state, q_m, dq_m_s, ref, u_v)


@kernel
def darc_step(params, state, t_s, q_m, dq_m_s, ref, u_v):
    """One 0.2 ms sample of DARC: the law, then the gradient step (eq. 8-9) driven by this sample's s_c."""
    _law(params, state, q_m, dq_m_s, ref, u_v)
    theta, law, rates = state.theta, state.law, params.darc_gamma
    phi, s_c, ts = law.phi, law.s_c, params.sample_period_s
    for j in range(8):
        phi_s = phi[0, j] * s_c[0] + phi[1, j] * s_c[1]
        theta[j] = theta[j] - ts * rates[j] * phi_s
    project_box(theta, params.lower, params.upper, theta)


@kernel
def diarc_step(params, state, t_s, q_m, dq_m_s, ref, u_v):
    """One 0.2 ms sample of DIARC: theta^ from the data up to this sample (eq. 25-28), the law, then dc^ (eq. 21-22).

    The first sample starts the estimator's filters instead of updating theta^.
    """
    theta, dc, u_previous_v, est, law = state
    started = est.clock[CLOCK_STARTED] > 0.0
    if started:
        estimator_update(params, theta, est, q_m, dq_m_s, u_previous_v)
    _law(params, state, q_m, dq_m_s, ref, u_v)
    if not started:
        estimator_start(params, est, q_m, dq_m_s, u_v)
    s_c, ts, gamma_d, dc_max = law.s_c, params.sample_period_s, params.gamma_d, params.dc_max_v
    for i in range(2):
        u_previous_v[i] = u_v[i]
        dc[i] = clip(dc[i] + ts * gamma_d[i] * s_c[i], -dc_max[i], dc_max[i])


@kernel(internal=True)
def log_theta(params, state, out):
    """DARC's log: theta_hat (8,)."""
    theta = state.theta
    for j in range(8):
        out[j] = theta[j]


@kernel(internal=True)
def log_diarc(params, state, out):
    """DIARC's log: theta_hat (8,), dc_hat (2,), gamma_diag (8,), gamma_lambda_max."""
    theta, dc, gamma = state.theta, state.dc, state.estimator.gamma
    for j in range(8):
        out[j] = theta[j]
        out[10 + j] = gamma[j, j]
    out[8] = dc[0]
    out[9] = dc[1]
    out[18] = state.estimator.clock[CLOCK_LAMBDA_MAX]


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


def _vec(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=float)


def _placeholder_estimator() -> EstimatorParams:
    """Estimator settings for DRC and DARC, which have no estimator (never read)."""
    z2 = np.ones(2)
    return EstimatorParams(
        np.zeros((2, 2, 2)), np.zeros((2, 2)), np.zeros((2, 2)), z2, z2, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0
    )


def _arc_params(
    gains: ArcGains,
    sample_period_s: float,
    u_max_v: np.ndarray,
    darc_gamma: np.ndarray | None = None,
    settings: EstimatorSettings | None = None,
    estimator: EstimatorParams | None = None,
) -> ArcParams:
    return ArcParams(
        float(sample_period_s),
        gains.lam.copy(),
        gains.ks.copy(),
        float(gains.friction_slope_s_m),
        gains.lower.copy(),
        gains.upper.copy(),
        _vec(u_max_v).copy(),
        np.zeros(8) if darc_gamma is None else _vec(darc_gamma).copy(),
        np.zeros(2) if settings is None else np.asarray(settings.gamma_d, dtype=float),
        np.zeros(2) if settings is None else np.asarray(settings.dc_max_v, dtype=float),
        estimator if estimator is not None else _placeholder_estimator(),
    )


class ArcController:
    """The shared DRC/DARC/DIARC machinery; subclasses say where theta^ and dc^ come from."""

    def __init__(self, gains: ArcGains | None = None) -> None:
        self.gains = gains or ArcGains()
        self.sample_period_s = 0.0
        self.u_max_v = np.array(U_MAX_V)
        self.params: ArcParams | None = None
        self.state = self._fresh_state(None)

    def _fresh_state(self, estimator: IndirectEstimator | None) -> ArcState:
        if estimator is None:
            gamma = np.zeros((8, 8))
            est = EstimatorState(
                gamma,
                np.zeros((2, 2, 4)),
                np.zeros(2),
                np.zeros(3),
                np.zeros((8, 2)),
                np.zeros(2),
                least_squares_work(8, 2),
            )
        else:
            est = estimator.state
        return ArcState(np.array(self.gains.theta0, dtype=float), np.zeros(2), np.zeros(2), est, law_work())

    def _make_params(self) -> ArcParams:
        return _arc_params(self.gains, self.sample_period_s, self.u_max_v)

    def reset(self, context: RunContext) -> None:
        self.sample_period_s = float(context.sample_period_s)
        self.u_max_v = np.asarray(context.u_max_v, dtype=float)
        self.state = self._fresh_state(None)
        self.params = self._make_params()

    @property
    def theta(self) -> np.ndarray:
        """theta^ (8,), volt units (the state array itself)."""
        return self.state.theta

    @theta.setter
    def theta(self, value: np.ndarray) -> None:
        self.state.theta[:] = value

    def kernel_arguments(self) -> tuple[ArcParams, ArcState]:
        """(params, state) for the compiled step; valid after ``reset``."""
        assert self.params is not None, "reset() must be called before update()"
        return self.params, self.state

    def update(self, measurement: Measurement, reference: ReferenceSample) -> np.ndarray:
        params, state = self.kernel_arguments()
        u_v = np.zeros(2)
        uncompiled(type(self).compiled.step)(
            params, state, float(measurement.t_s), _vec(measurement.q_m), _vec(measurement.dq_m_s), reference.row(), u_v
        )
        return u_v

    def state_for_logging(self) -> dict[str, np.ndarray]:
        params, state = self.kernel_arguments()
        return log_values(type(self).compiled, params, state)


class DRC(ArcController):
    """Deterministic robust control (C3): theta^ fixed.

    ``theta`` overrides theta0 (e.g. the true parameters, to test the
    feed-forward); nothing is estimated, so nothing is logged.
    """

    compiled = CompiledStep(drc_step)

    def __init__(self, gains: ArcGains | None = None, theta: Theta | None = None) -> None:
        if theta is not None:
            gains = ArcGains(**{**_gain_fields(gains or ArcGains()), "theta0": tuple(theta)})
        super().__init__(gains)


class DARC(ArcController):
    """Direct adaptive robust control (C1): gradient adaptation, eq. (8)-(9)."""

    compiled = CompiledStep(darc_step, log_theta, (("theta_hat", (8,)),))

    def __init__(self, gains: ArcGains | None = None, gamma: Rates = DARC_GAMMA) -> None:
        super().__init__(gains)
        self.gamma = np.asarray(gamma, dtype=float)

    def _make_params(self) -> ArcParams:
        return _arc_params(self.gains, self.sample_period_s, self.u_max_v, darc_gamma=self.gamma)


class DIARC(ArcController):
    """Integrated direct/indirect adaptive robust control (C2), section 4."""

    compiled = CompiledStep(
        diarc_step, log_diarc, (("theta_hat", (8,)), ("dc_hat", (2,)), ("gamma_diag", (8,)), ("gamma_lambda_max", ()))
    )

    def __init__(self, gains: ArcGains | None = None, estimator: EstimatorChoice | None = None) -> None:
        super().__init__(gains)
        self.estimator_settings = estimator or EstimatorSettings()
        self.estimator: IndirectEstimator | None = None

    def reset(self, context: RunContext) -> None:
        self.sample_period_s = float(context.sample_period_s)
        self.u_max_v = np.asarray(context.u_max_v, dtype=float)
        self.estimator = IndirectEstimator(self.estimator_settings, self.gains, self.sample_period_s)
        self.state = self._fresh_state(self.estimator)
        self.params = _arc_params(
            self.gains,
            self.sample_period_s,
            self.u_max_v,
            settings=self.estimator_settings,
            estimator=self.estimator.params,
        )

    @property
    def dc(self) -> np.ndarray:
        """dc^ (2,), volts."""
        return self.state.dc

    @property
    def u_previous_v(self) -> np.ndarray:
        return self.state.u_previous_v


def _gain_fields(gains: ArcGains) -> dict[str, object]:
    return {
        "lambda_1_s": gains.lambda_1_s,
        "ks_v_s_m": gains.ks_v_s_m,
        "friction_slope_s_m": gains.friction_slope_s_m,
        "theta0": gains.theta0,
        "theta_min": gains.theta_min,
        "theta_max": gains.theta_max,
    }
