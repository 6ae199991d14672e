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
:func:`drc_step`, :func:`darc_step` or :func:`diarc_step` around the shared
:func:`_law`; :func:`arc_step` picks one by ``ArcParams.law``, and
:func:`arc_log` the matching log. The three classes offer that one compiled
step to the loop through the plug-in protocol (``compiled``,
``kernel_arguments``; see :mod:`gantry_twin.controllers.base`) like any other
controller, so their loops compile once, together (docs/performance.md,
"Compile"); ``update()`` runs the plain-Python reference version.

DIARC's estimator (settings, filtered regression, least squares) is in
:mod:`gantry_twin.controllers.estimator`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from gantry_twin.controllers.base import (
    U_MAX_V,
    CompiledStep,
    Measurement,
    ReferenceSample,
    RunContext,
    log_values,
)
from gantry_twin.controllers.estimator import (
    CLOCK_LAMBDA_MAX,
    CLOCK_STARTED,
    EstimatorChoice,
    EstimatorParams,
    EstimatorSettings,
    EstimatorState,
    IndirectEstimator,
    estimator_start,
    estimator_update,
    placeholder_estimator,
)
from gantry_twin.controllers.law import ArcGains, LawWork, Theta, arc_law, law_work
from gantry_twin.numerics.estimation import (
    clip,
    least_squares_work,
    project_box,
)
from gantry_twin.numerics.jit import kernel
from gantry_twin.numerics.jit import reference as uncompiled
from gantry_twin.plant.model import THETA_NAMES
from gantry_twin.settings import Range, Vector

#: DARC's adaptation rates (paper section 5).
DARC_GAMMA = (10.0, 10.0, 10.0, 10.0, 1.0, 1.0, 10000.0, 10000.0)
#: Adaptation rates of theta^, one per parameter: at most 1e8, where one sample's step (Ts gamma = 2e4)
#: already crosses the whole theta box for a 0.1 mm/s sliding error: a relay, not an adaptation.
Rates = Vector(Range(0.0, 1.0e8), THETA_NAMES)

#: ArcParams.law: which controller's step :func:`arc_step` runs.
LAW_DRC, LAW_DARC, LAW_DIARC = 0, 1, 2


class ArcParams(NamedTuple):
    """Everything fixed during a run of DRC, DARC or DIARC (float64 arrays, SI/volts).

    lam (2,) 1/s and ks (2,)
    V/(m/s): diagonals of Lambda and Ks; lower, upper (8,): theta bounds;
    u_max_v (2,); darc_gamma (8,): DARC's rates; gamma_d (2,), dc_max_v (2,):
    DIARC's dc^ law; estimator: DIARC's (placeholders for the others);
    law: LAW_DRC, LAW_DARC or LAW_DIARC.
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
    law: int


class ArcState(NamedTuple):
    """The controller's whole state: theta (8,), dc (2,) volts, the last command (2,) volts,
    the estimator's state and the law's per-sample work (its u_v is the command)."""

    theta: np.ndarray
    dc: np.ndarray
    u_previous_v: np.ndarray
    estimator: EstimatorState
    law: LawWork


@kernel(inline=True, internal=True, nrt=False)
def _law(params, state, q_m, dq_m_s, ref, u_v):
    """The shared law (eq. 13-14, 17, 21) with this controller's theta^ and dc^; the command into u_v (2,) V."""
    law = state.law
    arc_law(
        q_m, dq_m_s, ref, state.theta, state.dc, params.lam, params.ks, params.friction_slope_s_m, params.u_max_v, law
    )
    u_v[0] = law.u_v[0]
    u_v[1] = law.u_v[1]


@kernel(inline=True, nrt=False)
def drc_step(params, state, t_s, q_m, dq_m_s, ref, u_v):
    """One 0.2 ms sample of DRC: the law with theta^ fixed; the command (volts) into u_v (2,)."""
    _law(params, state, q_m, dq_m_s, ref, u_v)


@kernel(inline=True, nrt=False)
def darc_step(params, state, t_s, q_m, dq_m_s, ref, u_v):
    """One 0.2 ms sample of DARC: the law, then the gradient step (eq. 8-9) driven by this sample's s_c."""
    _law(params, state, q_m, dq_m_s, ref, u_v)
    theta, law, rates = state.theta, state.law, params.darc_gamma
    phi, s_c, ts = law.phi, law.s_c, params.sample_period_s
    for j in range(8):
        phi_s = phi[0, j] * s_c[0] + phi[1, j] * s_c[1]
        theta[j] = theta[j] - ts * rates[j] * phi_s
    project_box(theta, params.lower, params.upper, theta)


@kernel(inline=True, nrt=False)
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


@kernel(nrt=False)
def arc_step(params, state, t_s, q_m, dq_m_s, ref, u_v):
    """One 0.2 ms sample of the controller ``params.law`` names (DRC, DARC or DIARC); the command into u_v (2,) V."""
    law = params.law
    if law == LAW_DIARC:
        diarc_step(params, state, t_s, q_m, dq_m_s, ref, u_v)
    elif law == LAW_DARC:
        darc_step(params, state, t_s, q_m, dq_m_s, ref, u_v)
    else:
        drc_step(params, state, t_s, q_m, dq_m_s, ref, u_v)


@kernel(inline=True, internal=True, nrt=False)
def log_theta(params, state, out):
    """DARC's log: theta_hat (8,)."""
    theta = state.theta
    for j in range(8):
        out[j] = theta[j]


@kernel(inline=True, internal=True, nrt=False)
def log_diarc(params, state, out):
    """DIARC's log: theta_hat (8,), dc_hat (2,), gamma_diag (8,), gamma_lambda_max."""
    theta, dc, gamma = state.theta, state.dc, state.estimator.gamma
    for j in range(8):
        out[j] = theta[j]
        out[10 + j] = gamma[j, j]
    out[8] = dc[0]
    out[9] = dc[1]
    out[18] = state.estimator.clock[CLOCK_LAMBDA_MAX]


@kernel(internal=True, nrt=False)
def arc_log(params, state, out):
    """The log of the controller ``params.law`` names: DIARC's :func:`log_diarc`, DARC's :func:`log_theta`; DRC none."""
    law = params.law
    if law == LAW_DIARC:
        log_diarc(params, state, out)
    elif law == LAW_DARC:
        log_theta(params, state, out)


def _vec(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=float)


def _arc_params(
    law: int,
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
        estimator if estimator is not None else placeholder_estimator(),
        law,
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
        return _arc_params(LAW_DRC, self.gains, self.sample_period_s, self.u_max_v)

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

    compiled = CompiledStep(arc_step, arc_log)

    def __init__(self, gains: ArcGains | None = None, theta: Theta | None = None) -> None:
        if theta is not None:
            gains = ArcGains(**{**_gain_fields(gains or ArcGains()), "theta0": tuple(theta)})
        super().__init__(gains)


class DARC(ArcController):
    """Direct adaptive robust control (C1): gradient adaptation, eq. (8)-(9)."""

    compiled = CompiledStep(arc_step, arc_log, (("theta_hat", (8,)),))

    def __init__(self, gains: ArcGains | None = None, gamma: Rates = DARC_GAMMA) -> None:
        super().__init__(gains)
        self.gamma = np.asarray(gamma, dtype=float)

    def _make_params(self) -> ArcParams:
        return _arc_params(LAW_DARC, self.gains, self.sample_period_s, self.u_max_v, darc_gamma=self.gamma)


class DIARC(ArcController):
    """Integrated direct/indirect adaptive robust control (C2), section 4."""

    compiled = CompiledStep(
        arc_step, arc_log, (("theta_hat", (8,)), ("dc_hat", (2,)), ("gamma_diag", (8,)), ("gamma_lambda_max", ()))
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
            LAW_DIARC,
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
