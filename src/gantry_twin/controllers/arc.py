"""DRC (C3), DARC (C1) and DIARC (C2): one law, three sources of theta^.

All three apply :func:`gantry_twin.controllers.law.arc_law`; they differ only
in how theta^ (and for DIARC dc^) move after each sample:

* DRC: theta^ = theta0, fixed (paper C3, "Gamma = 0").
* DARC: gradient adaptation theta^' = Proj(-Gamma Phi^T s_c) with diagonal
  Gamma and the discontinuous projection of eq. (9).
* DIARC: theta^ from the indirect least-squares estimator of section 4.2
  (:class:`IndirectEstimator`) and the fast dynamic compensation
  dc^' = Proj(gamma_d s_c), |dc^| <= dcmax (eq. 21-22).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gantry_twin.controllers.base import Measurement, ReferenceSample, RunContext
from gantry_twin.controllers.law import ArcGains, LawTerms, arc_law
from gantry_twin.estimation import (
    FilterDiscretisation,
    LeastSquaresSettings,
    discretise_filter,
    filter_acceleration,
    friction_shape,
    least_squares_step,
    project_box,
)

#: DARC's adaptation rates (paper section 5).
DARC_GAMMA = (10.0, 10.0, 10.0, 10.0, 1.0, 1.0, 10000.0, 10000.0)


class ArcController:
    """The shared DRC/DARC/DIARC machinery; subclasses move theta^ and dc^."""

    def __init__(self, gains: ArcGains | None = None) -> None:
        self.gains = gains or ArcGains()
        self.theta = np.array(self.gains.theta0, dtype=float)
        self.sample_period_s = 0.0
        self.u_max_v = np.full(2, 10.0)

    def reset(self, context: RunContext) -> None:
        self.theta = np.array(self.gains.theta0, dtype=float)
        self.sample_period_s = context.sample_period_s
        self.u_max_v = np.asarray(context.u_max_v, dtype=float)

    def dynamic_compensation(self) -> np.ndarray | None:
        """dc^ in volts (X, Y), or None for a controller without it."""
        return None

    def before_control(self, measurement: Measurement) -> None:
        """Hook: estimation that uses data up to this sample (DIARC)."""

    def after_control(self, measurement: Measurement, terms: LawTerms) -> None:
        """Hook: adaptation driven by this sample's s_c (DARC, DIARC's dc^)."""

    def update(self, measurement: Measurement, reference: ReferenceSample) -> np.ndarray:
        self.before_control(measurement)
        terms = arc_law(
            measurement.q_m,
            measurement.dq_m_s,
            reference.q_d,
            reference.dq_d,
            reference.ddq_d,
            reference.alpha,
            reference.dalpha,
            reference.ddalpha,
            self.theta,
            self.dynamic_compensation(),
            self.gains,
            self.u_max_v,
        )
        self.after_control(measurement, terms)
        return terms.u_v

    def state_for_logging(self) -> dict[str, np.ndarray]:
        return {"theta_hat": self.theta.copy()}


class DRC(ArcController):
    """Deterministic robust control (C3): theta^ fixed.

    ``theta`` overrides theta0 (e.g. the true parameters, to test the
    feed-forward); nothing is estimated, so nothing is logged.
    """

    def __init__(self, gains: ArcGains | None = None, theta: tuple[float, ...] | None = None) -> None:
        if theta is not None:
            gains = ArcGains(**{**_gain_fields(gains or ArcGains()), "theta0": tuple(theta)})
        super().__init__(gains)

    def state_for_logging(self) -> dict[str, np.ndarray]:
        return {}


class DARC(ArcController):
    """Direct adaptive robust control (C1): gradient adaptation, eq. (8)-(9)."""

    def __init__(self, gains: ArcGains | None = None, gamma: tuple[float, ...] = DARC_GAMMA) -> None:
        super().__init__(gains)
        self.gamma = np.asarray(gamma, dtype=float)

    def after_control(self, measurement: Measurement, terms: LawTerms) -> None:
        step = -self.sample_period_s * self.gamma * (terms.phi.T @ terms.s_c)
        self.theta = project_box(self.theta + step, self.gains.lower, self.gains.upper)


@dataclass(frozen=True)
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

    filter_hz: tuple[float, float] = (250.0, 150.0)
    filter_zeta: float = 0.7
    least_squares: LeastSquaresSettings = field(default_factory=LeastSquaresSettings)
    gamma_d: tuple[float, float] = (1.0e4, 1.0e4)
    dc_max_v: tuple[float, float] = (0.5, 1.5)
    settle_s: float = 0.02


#: The twin's recommended estimator: 50 Hz filters, which keep the encoder's
#: 0.5 um quantisation noise out of x_f'' (control-spec section 7).
RECOMMENDED_ESTIMATOR = EstimatorSettings(filter_hz=(50.0, 50.0))


class IndirectEstimator:
    """Filtered regression (eq. 25) and least squares (eq. 27-28) for both axes.

    Per axis, four signals pass through the same Hf: the measured position
    (first-order hold: it moves continuously between samples), Sf(q'), the
    constant 1 and the applied input u (zero-order hold: the DAC holds u and
    the measured velocity is the mean over the last sample). Filter states are
    ``z[axis]`` of shape (2, 4): rows [w_f, w_f'], columns [q, Sf, 1, u].
    """

    def __init__(self, settings: EstimatorSettings, gains: ArcGains, sample_period_s: float) -> None:
        self.settings = settings
        self.gains = gains
        self.sample_period_s = sample_period_s
        self.filters: list[FilterDiscretisation] = [
            discretise_filter(2.0 * np.pi * hz, settings.filter_zeta, sample_period_s) for hz in settings.filter_hz
        ]
        self.gamma = np.diag(np.asarray(settings.least_squares.gamma0_diag, dtype=float))
        self.lambda_max = float(np.max(settings.least_squares.gamma0_diag))
        self.z = np.zeros((2, 2, 4))
        self.previous_q_m = np.zeros(2)
        self.time_s = 0.0
        self.started = False

    def start(self, q_m: np.ndarray, dq_m_s: np.ndarray, u_v: np.ndarray) -> None:
        """Put each filter in steady state for the first sample's inputs."""
        sf = friction_shape(dq_m_s, self.gains.friction_slope_s_m)
        for axis, disc in enumerate(self.filters):
            lag = 2.0 * disc.zeta / disc.wn_rad_s
            self.z[axis] = [[q_m[axis] - lag * dq_m_s[axis], sf[axis], 1.0, u_v[axis]], [dq_m_s[axis], 0.0, 0.0, 0.0]]
        self.previous_q_m = np.array(q_m, dtype=float)
        self.started = True

    def regression(
        self, q_m: np.ndarray, dq_m_s: np.ndarray, u_previous_v: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Advance the filters to this sample; return (gamma_f 8 x 2, u_f 2)."""
        ts = self.sample_period_s
        sf = friction_shape(dq_m_s, self.gains.friction_slope_s_m)
        g = np.zeros((8, 2))
        u_f = np.zeros(2)
        for axis, disc in enumerate(self.filters):
            start = np.array([self.previous_q_m[axis], sf[axis], 1.0, u_previous_v[axis]])
            slope = np.array([(q_m[axis] - self.previous_q_m[axis]) / ts, 0.0, 0.0, 0.0])
            self.z[axis] = disc.phi @ self.z[axis] + np.outer(disc.hold, start) + np.outer(disc.ramp, slope)
            z = self.z[axis]
            g[axis, axis] = filter_acceleration(z[:, 0], disc, q_m[axis])
            g[2 + axis, axis] = z[1, 0]
            g[4 + axis, axis] = z[0, 1]
            g[6 + axis, axis] = -z[0, 2]
            u_f[axis] = z[0, 3]
        self.previous_q_m = np.array(q_m, dtype=float)
        return g, u_f

    def update(self, theta: np.ndarray, q_m: np.ndarray, dq_m_s: np.ndarray, u_previous_v: np.ndarray) -> None:
        """One sample: filter, then least squares on theta (in place)."""
        g, u_f = self.regression(q_m, dq_m_s, u_previous_v)
        self.time_s += self.sample_period_s
        if self.time_s < self.settings.settle_s:
            return
        self.lambda_max = least_squares_step(
            theta,
            self.gamma,
            g,
            u_f,
            self.settings.least_squares,
            self.gains.lower,
            self.gains.upper,
            self.sample_period_s,
        )


class DIARC(ArcController):
    """Integrated direct/indirect adaptive robust control (C2), section 4."""

    def __init__(self, gains: ArcGains | None = None, estimator: EstimatorSettings | None = None) -> None:
        super().__init__(gains)
        self.estimator_settings = estimator or EstimatorSettings()
        self.dc = np.zeros(2)
        self.u_previous_v = np.zeros(2)
        self.estimator: IndirectEstimator | None = None

    def reset(self, context: RunContext) -> None:
        super().reset(context)
        self.dc = np.zeros(2)
        self.u_previous_v = np.zeros(2)
        self.estimator = IndirectEstimator(self.estimator_settings, self.gains, context.sample_period_s)

    def dynamic_compensation(self) -> np.ndarray:
        return self.dc

    def before_control(self, measurement: Measurement) -> None:
        assert self.estimator is not None, "reset() must be called before update()"
        if self.estimator.started:
            self.estimator.update(self.theta, measurement.q_m, measurement.dq_m_s, self.u_previous_v)

    def after_control(self, measurement: Measurement, terms: LawTerms) -> None:
        assert self.estimator is not None
        if not self.estimator.started:
            self.estimator.start(measurement.q_m, measurement.dq_m_s, terms.u_v)
        self.u_previous_v = terms.u_v
        dc_max = np.asarray(self.estimator_settings.dc_max_v)
        step = self.sample_period_s * np.asarray(self.estimator_settings.gamma_d) * terms.s_c
        self.dc = project_box(self.dc + step, -dc_max, dc_max)

    def state_for_logging(self) -> dict[str, np.ndarray]:
        assert self.estimator is not None
        return {
            "theta_hat": self.theta.copy(),
            "dc_hat": self.dc.copy(),
            "gamma_diag": np.diag(self.estimator.gamma).copy(),
            "gamma_lambda_max": np.array([self.estimator.lambda_max]),
        }


def _gain_fields(gains: ArcGains) -> dict[str, object]:
    return {
        "lambda_1_s": gains.lambda_1_s,
        "ks_v_s_m": gains.ks_v_s_m,
        "friction_slope_s_m": gains.friction_slope_s_m,
        "theta0": gains.theta0,
        "theta_min": gains.theta_min,
        "theta_max": gains.theta_max,
    }
