"""What a run is judged by (paper section 5): contour error and estimate accuracy."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gantry_twin.plant import THETA_NAMES
from gantry_twin.trace import Trace


@dataclass(frozen=True)
class ContourMetrics:
    """rms and max of |eps_c| over a window, micrometres."""

    rms_um: float
    max_um: float
    window_s: tuple[float, float]


def window_mask(t_s: np.ndarray, window_s: tuple[float, float]) -> np.ndarray:
    """Samples with window[0] <= t < window[1]."""
    mask = (t_s >= window_s[0]) & (t_s < window_s[1])
    if not mask.any():
        raise ValueError(f"window {window_s} s holds no sample of a run of {t_s[-1]:.3f} s")
    return mask


def contour_metrics(trace: Trace, window_s: tuple[float, float]) -> ContourMetrics:
    """The paper's ||eps_c||_rms and eps_cM over the window."""
    eps = np.abs(trace.eps_c_m[window_mask(trace.t_s, window_s)]) * 1e6
    return ContourMetrics(float(np.sqrt(np.mean(eps**2))), float(eps.max()), window_s)


def steady_estimates(trace: Trace, window_s: tuple[float, float]) -> np.ndarray | None:
    """Mean theta^ over the window (e.g. the last period), or None if not estimated."""
    theta = trace.controller_state.get("theta_hat")
    if theta is None:
        return None
    return theta[window_mask(trace.t_s, window_s)].mean(axis=0)


def steady_true_parameters(trace: Trace, window_s: tuple[float, float]) -> np.ndarray:
    """Mean true theta over the same window (volt units), the value :func:`steady_estimates` is judged against.

    It moves when the run has plant changes (a payload picked up, drifting
    friction); a window before the change is judged against the old value.
    """
    return trace.true_parameters_t()[window_mask(trace.t_s, window_s)].mean(axis=0)


def error_pct(estimate: float, true: float) -> float | None:
    """100 (estimate - true) / true; None where the true value is 0 (dN)."""
    return None if true == 0.0 else float(100.0 * (estimate - true) / true)


def estimate_errors_pct(estimate: np.ndarray, true_theta: np.ndarray) -> dict[str, float | None]:
    """:func:`error_pct` of each parameter, by name."""
    return {name: error_pct(est, tru) for name, est, tru in zip(THETA_NAMES, estimate, true_theta, strict=True)}


def axial_rms_um(trace: Trace, window_s: tuple[float, float]) -> np.ndarray:
    """rms of each axis's tracking error e = q - q_d over the window, micrometres (X, Y)."""
    e = trace.e_m[window_mask(trace.t_s, window_s)] * 1e6
    return np.sqrt(np.mean(e**2, axis=0))


@dataclass(frozen=True)
class CommandMetrics:
    """How hard a run drove the motors, over the whole run, per axis (X, Y).

    max_abs_u_v: largest |u|, volts; saturated_fraction: the fraction of
    samples at the DAC limit (|u| = u_max, the loop clips to exactly it).
    """

    max_abs_u_v: np.ndarray
    saturated_fraction: np.ndarray


def command_metrics(trace: Trace, u_max_v: np.ndarray) -> CommandMetrics:
    """:class:`CommandMetrics` of the recorded (clipped) command; u_max_v (2,) the DAC limits, volts."""
    u = np.abs(trace.u_v[: trace.filled])
    limit = np.asarray(u_max_v, dtype=float)
    return CommandMetrics(u.max(axis=0), np.mean(u >= limit, axis=0))
