"""Whether each of DIARC's estimates in summary.json can be trusted for this run.

Judged from what the controller measured and commanded, with the estimator's own filters, friction shape
and reversal gate (:mod:`gantry_twin.health.excitation`), over the run from its start to the end of the
estimates window. An estimate is trustworthy when its axis slid enough, its regressor errors plus its fit
gap (to the least-squares fit of eq. 25 over the same data) are within ``max_error``, and its excitation is
above that fit's rms residual; otherwise ``why`` says which failed. :meth:`EstimateConfidence.statistics`
holds all the judgement needs (summary.json's ``confidence``), so :func:`judge` can judge a finished run again.

(docs/estimator-envelope.md, "Honest confidence")
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gantry_twin.health.excitation import (
    AXIS_OF,
    COLUMN_OF,
    ExcitationSettings,
    FilteredRegressors,
    accumulate_information,
    accumulate_moment,
    estimate_bias,
    normalised_excitation,
    quantisation_noise,
)
from gantry_twin.loop.trace import Trace
from gantry_twin.plant.model import AXES, THETA_NAMES


class EstimateConfidence:
    """An Observer: the estimator's regression up to the end of ``window_s``, then :meth:`verdicts`."""

    def __init__(self, settings: ExcitationSettings, window_s: tuple[float, float]) -> None:
        self.settings = settings
        self.window_s = window_s
        self._regressors: FilteredRegressors | None = None
        self._info = np.zeros((2, 5, 5))  # sum [g, u_f] [g, u_f]^T dt over the sliding samples used
        self._moment = np.zeros((2, 2, 4))  # the friction column's error: sum g e dt, sum |g| d dt
        self._used = np.zeros(2)  # samples in the information
        self._sliding = np.zeros(2)  # samples in the estimates window where the axis slid
        self._window_samples = 0
        self._samples = 0  # up to the end of the estimates window
        self._first_s: float | None = None
        self._ts = 0.0
        self._no_blocks, self._no_moving, self._no_moments = (
            np.empty((1, 2, 5, 5)),
            np.empty((1, 2)),
            np.empty((1, 2, 2, 4)),
        )

    def on_start(self, run: object, trace: Trace) -> None:
        pass

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        """Sample by sample in a fixed order (the kernels of the monitor): the same sums however the run is cut."""
        if self._regressors is None:
            self._ts = trace.sample_period_s
            self._regressors = FilteredRegressors(self.settings, self._ts)
        rows = trace.rows(start, stop)
        g, speed = self._regressors.advance(trace.q_meas_m[rows], trace.u_v[rows])
        t = trace.t_s[rows]
        if self._first_s is None and len(t):
            self._first_s = float(t[0])
        seen = t < self.window_s[1]
        inside = seen & (t >= self.window_s[0])
        sliding = speed >= self.settings.sliding_speed_m_s
        weight = np.where(sliding & seen[:, None], self._ts, 0.0)
        augmented = np.concatenate([g, self._regressors.u_f[:, :, None]], axis=2)
        never = np.iinfo(np.int64).max  # one open period: the whole span
        accumulate_information(
            augmented, weight, start, never, self._info, self._used, self._no_blocks, self._no_moving
        )
        error, size = self._regressors.friction_error, self._regressors.reversal_error
        accumulate_moment(g, error, size, weight, start, never, self._moment, self._no_moments)
        self._sliding += (sliding & inside[:, None]).sum(axis=0)
        self._window_samples += int(inside.sum())
        self._samples += int(seen.sum())

    def on_end(self, trace: Trace) -> None:
        pass

    def statistics(self) -> dict[str, Any]:
        """What :func:`judge` needs (summary.json's ``confidence``): sums over the run up to the window's end."""
        ex = self.settings
        noise = quantisation_noise(ex, ex.resolution_m, self._ts) if self._ts else np.zeros((2, 2))
        return {
            "span_s": [self._first_s if self._first_s is not None else 0.0, float(self.window_s[1])],
            "seconds": self._samples * self._ts,
            "window_sliding_fraction": (self._sliding / max(self._window_samples, 1)).tolist(),
            "information": self._info.tolist(),
            "friction_moment": self._moment.tolist(),
            "quantisation_noise": noise.tolist(),
            "scale": list(ex.scale),
        }

    def verdicts(self, estimate: np.ndarray) -> dict[str, dict[str, Any]]:
        """Per parameter of ``estimate`` (8,), the run's estimates: see :func:`judge`."""
        return judge(self.statistics(), estimate, self.settings)


def judge(stats: dict[str, Any], estimate: np.ndarray, settings: ExcitationSettings) -> dict[str, dict[str, Any]]:
    """Per parameter: trustworthy, why (None when trustworthy), excitation_v, bias_bound_pct, fit_gap_pct.

    ``stats``: :meth:`EstimateConfidence.statistics`; ``settings``: the
    thresholds ``max_error``, ``min_moving_fraction`` (the rest is in stats).
    """
    info = np.asarray(stats["information"], dtype=float)
    regression, target, target_sq = info[:, :4, :4], info[:, :4, 4], info[:, 4, 4]
    scale = np.asarray(stats["scale"], dtype=float)
    seconds = max(float(stats["seconds"]), 1e-300)
    _, parameter_v = normalised_excitation(regression, scale, seconds)
    empty = np.trace(regression, axis1=-2, axis2=-1) <= 0.0  # an axis without a sample used: nothing excited
    parameter_v = np.where(empty[AXIS_OF], 0.0, parameter_v)
    bias = estimate_bias(
        parameter_v,
        scale,
        np.asarray(stats["quantisation_noise"], dtype=float),
        regression,
        np.asarray(stats["friction_moment"], dtype=float),
        correlated=True,
    )
    eps = 1e-12 * np.trace(regression, axis1=-2, axis2=-1)[:, None, None] + 1e-300
    fit = np.linalg.solve(regression + eps * np.eye(4), target[:, :, None])[:, :, 0]  # (2 axes, 4 columns)
    residual_v = np.sqrt(np.clip(target_sq - np.einsum("ai,ai->a", target, fit), 0.0, None) / seconds)
    gap = np.abs(fit[AXIS_OF, COLUMN_OF] - np.asarray(estimate, dtype=float)) / scale
    gap = np.where(parameter_v > 0.0, gap, np.inf)
    moving = np.asarray(stats["window_sliding_fraction"], dtype=float)
    out = {}
    for j, name in enumerate(THETA_NAMES):
        axis = AXIS_OF[j]
        why = None
        total = bias[j] + gap[j]
        if moving[axis] < settings.min_moving_fraction:
            why = f"axis {AXES[axis]} slid in {100 * moving[axis]:.0f} % of the window"
        elif parameter_v[j] <= residual_v[axis]:
            why = f"not excited: {parameter_v[j]:.3g} V <= the fit's residual {residual_v[axis]:.3g} V (eq. 29)"
        elif total > settings.max_error:
            why = (
                f"regressor errors and the gap to the least-squares fit ({100 * gap[j]:.3g} %) may bias it by up to "
                f"{100 * total:.3g} % (> {100 * settings.max_error:g} %)"
            )
        out[name] = {
            "trustworthy": why is None,
            "why": why,
            "excitation_v": float(parameter_v[j]),
            "bias_bound_pct": float(100 * total) if np.isfinite(total) else None,
            "fit_gap_pct": float(100 * gap[j]) if np.isfinite(gap[j]) else None,
        }
    return out
