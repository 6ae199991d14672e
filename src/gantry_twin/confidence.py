"""Whether each of DIARC's estimates in summary.json can be trusted for this run (issue 16).

Over the estimates window, the same judgement the health monitor makes
every period (:mod:`gantry_twin.excitation`, :class:`gantry_twin.monitor.ExcitationSettings`),
from what the controller measured, with the estimator's own filters, friction
shape and reversal gate. An estimate is trustworthy when

* its axis slid in at least ``min_moving_fraction`` of the window;
* it is excited: ``parameter_v`` (eq. 29, the rms signature of a 100 %
  change that the axis' other parameters cannot mimic) at least
  ``min_parameter_v``;
* its regressor errors (encoder quantisation in x_f'', x_f'; the friction
  column's gap from sign(v)) bound its relative bias by ``max_bias``.

Otherwise ``why`` says which failed, with the numbers.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gantry_twin.excitation import (
    AXIS_OF,
    FilteredRegressors,
    accumulate_information,
    accumulate_moment,
    estimate_bias,
    normalised_excitation,
    quantisation_noise,
)
from gantry_twin.monitor import ExcitationSettings
from gantry_twin.plant import AXES, THETA_NAMES
from gantry_twin.trace import Trace


class EstimateConfidence:
    """An Observer: excitation and regressor errors of the estimator over ``window_s``, then :meth:`verdicts`."""

    def __init__(self, settings: ExcitationSettings, window_s: tuple[float, float]) -> None:
        self.settings = settings
        self.window_s = window_s
        self._regressors: FilteredRegressors | None = None
        self._info = np.zeros((2, 4, 4))
        self._moment = np.zeros((2, 4))  # sum of |g| Hf[1 - |Sf|] dt over the samples used
        self._sliding = np.zeros(2)  # samples in the window where the axis slid
        self._window_samples = 0
        self._ts = 0.0
        self._no_blocks, self._no_moving, self._no_moments = (
            np.empty((1, 2, 4, 4)),
            np.empty((1, 2)),
            np.empty((1, 2, 4)),
        )

    def on_start(self, run: object, trace: Trace) -> None:
        pass

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        """Sample by sample in a fixed order (the kernels of the monitor): the same sums however the run is cut."""
        if self._regressors is None:
            self._ts = trace.sample_period_s
            self._regressors = FilteredRegressors(self.settings, self._ts)
        rows = trace.rows(start, stop)
        g, speed = self._regressors.advance(trace.q_meas_m[rows])
        t = trace.t_s[rows]
        inside = (t >= self.window_s[0]) & (t < self.window_s[1])
        weight = np.where((speed >= self.settings.sliding_speed_m_s) & inside[:, None], self._ts, 0.0)
        never = np.iinfo(np.int64).max  # one open period: the whole window
        accumulate_information(g, weight, start, never, self._info, self._sliding, self._no_blocks, self._no_moving)
        accumulate_moment(g, self._regressors.deficit, weight, start, never, self._moment, self._no_moments)
        self._window_samples += int(inside.sum())

    def on_end(self, trace: Trace) -> None:
        pass

    def verdicts(self) -> dict[str, dict[str, Any]]:
        """Per parameter: trustworthy, why (None when trustworthy), excitation_v, bias_bound_pct."""
        ex = self.settings
        seen = max(self._window_samples * self._ts, 1e-300)
        scale = np.asarray(ex.scale, dtype=float)
        _, parameter_v = normalised_excitation(self._info, scale, seen)
        noise = quantisation_noise(ex, ex.resolution_m, self._ts) if self._ts else np.zeros((2, 2))
        bias = estimate_bias(parameter_v, scale, noise, self._info, self._moment)
        moving = self._sliding / max(self._window_samples, 1)
        out = {}
        for j, name in enumerate(THETA_NAMES):
            axis = AXIS_OF[j]
            why = None
            if moving[axis] < ex.min_moving_fraction:
                why = f"axis {AXES[axis]} slid in {100 * moving[axis]:.0f} % of the window"
            elif parameter_v[j] < ex.min_parameter_v:
                why = f"not excited: {parameter_v[j]:.3g} V < {ex.min_parameter_v:g} V (eq. 29)"
            elif bias[j] > ex.max_bias:
                why = f"regressor errors may bias it by up to {100 * bias[j]:.3g} % (> {100 * ex.max_bias:g} %)"
            out[name] = {
                "trustworthy": why is None,
                "why": why,
                "excitation_v": float(parameter_v[j]),
                "bias_bound_pct": float(100 * bias[j]) if np.isfinite(bias[j]) else None,
            }
        return out
