"""An example compiled controller plug-in for gantry-twin.

    u_i = clip(-kp_i e_i - kd_i e_i' + kv_i x_d,i' + ka_i x_d,i'')     (volts)

The per-sample arithmetic is written once, in :func:`step` (a numba kernel
over the controller's parameter and state tuples). The compiled loop calls
it compiled; ``update()`` (the Python loop) calls the same function
uncompiled (``step.py_func``), so both backends give the same trace.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from gantry_twin.controllers.base import (
    REF_DDQ,
    REF_DQ,
    REF_Q,
    U_MAX_V,
    CompiledStep,
    Measurement,
    ReferenceSample,
    RunContext,
)


class Gains(NamedTuple):
    """Per-axis gains (X, Y) and the actuator limits, as float64 arrays."""

    kp_v_m: np.ndarray
    kd_v_s_m: np.ndarray
    kv_v_s_m: np.ndarray
    ka_v_s2_m: np.ndarray
    u_max_v: np.ndarray


class Memory(NamedTuple):
    """What the controller remembers: the largest |e| so far per axis, metres."""

    peak_error_m: np.ndarray


@numba.njit(cache=True)
def step(params, state, t_s, q_m, dq_m_s, ref, u_v):
    """One 0.2 ms sample: the command (volts) into u_v (2,); updates state in place."""
    peak = state.peak_error_m
    for i in range(2):
        e = q_m[i] - ref[REF_Q + i]
        de = dq_m_s[i] - ref[REF_DQ + i]
        u = -params.kp_v_m[i] * e - params.kd_v_s_m[i] * de + params.kv_v_s_m[i] * ref[REF_DQ + i]
        u = u + params.ka_v_s2_m[i] * ref[REF_DDQ + i]
        u_v[i] = min(max(u, -params.u_max_v[i]), params.u_max_v[i])
        if abs(e) > peak[i]:
            peak[i] = abs(e)


@numba.njit(cache=True)
def log(params, state, out):
    """The logged values in the order of the layout: peak_error_m (2,)."""
    out[0] = state.peak_error_m[0]
    out[1] = state.peak_error_m[1]


class ExamplePD:
    """Per-axis PD + feed-forward with the compiled step; gains per axis (X, Y)."""

    compiled = CompiledStep(step, log, (("peak_error_m", (2,)),))

    def __init__(
        self, kp_v_m=(10000.0, 10000.0), kd_v_s_m=(100.0, 100.0), kv_v_s_m=(0.5, 0.7), ka_v_s2_m=(0.12, 0.5)
    ) -> None:
        self.gains = (kp_v_m, kd_v_s_m, kv_v_s_m, ka_v_s2_m)
        self.params = Gains(*(np.asarray(g, dtype=float) for g in self.gains), np.array(U_MAX_V))
        self.state = Memory(np.zeros(2))

    def reset(self, context: RunContext) -> None:
        self.params = Gains(
            *(np.asarray(g, dtype=float) for g in self.gains), np.asarray(context.u_max_v, dtype=float).copy()
        )
        self.state = Memory(np.zeros(2))

    def kernel_arguments(self) -> tuple[Gains, Memory]:
        return self.params, self.state

    def update(self, measurement: Measurement, reference: ReferenceSample) -> np.ndarray:
        u_v = np.zeros(2)
        step.py_func(
            self.params,
            self.state,
            measurement.t_s,
            np.asarray(measurement.q_m, dtype=float),
            np.asarray(measurement.dq_m_s, dtype=float),
            reference.row(),
            u_v,
        )
        return u_v

    def state_for_logging(self) -> dict[str, np.ndarray]:
        return {"peak_error_m": self.state.peak_error_m.copy()}
