"""The compiled-controller protocol with a plug-in defined here: any controller with a compiled step runs compiled.

A PI controller with a logged integral (state updated in place, a scalar and
a vector in its log layout) runs on both backends: the traces, the logged
state and the controller object after the run must agree to the bit, and the
compiled run must really be the compiled loop (no update() call).
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np
import pytest

from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers.base import REF_DQ, REF_Q, CompiledStep, compiled_step_of, log_values
from gantry_twin.simulate import compiled_available, loop_needs_compiling


class Gains(NamedTuple):
    kp_v_m: float
    ki_v_s_m: float
    kd_v_s_m: float
    u_max_v: np.ndarray


class Integral(NamedTuple):
    integral_m_s: np.ndarray  # (2,)
    samples: np.ndarray  # (1,)


@numba.njit
def pi_step(params, state, t_s, q_m, dq_m_s, ref, u_v):
    for i in range(2):
        e = q_m[i] - ref[REF_Q + i]
        state.integral_m_s[i] += e * 2e-4
        de = dq_m_s[i] - ref[REF_DQ + i]
        u = -params.kp_v_m * e - params.ki_v_s_m * state.integral_m_s[i] - params.kd_v_s_m * de
        u_v[i] = min(max(u, -params.u_max_v[i]), params.u_max_v[i])
    state.samples[0] += 1.0


@numba.njit
def pi_log(params, state, out):
    out[0] = state.integral_m_s[0]
    out[1] = state.integral_m_s[1]
    out[2] = state.samples[0]


class PI:
    compiled = CompiledStep(pi_step, pi_log, (("integral_m_s", (2,)), ("samples", ())))

    def __init__(self) -> None:
        self.updates = 0

    def reset(self, context):  # noqa: ANN001, ANN201
        self.params = Gains(20000.0, 1.0e5, 150.0, np.asarray(context.u_max_v, dtype=float))
        self.state = Integral(np.zeros(2), np.zeros(1))

    def kernel_arguments(self):  # noqa: ANN201
        return self.params, self.state

    def update(self, measurement, reference):  # noqa: ANN001, ANN201
        self.updates += 1
        u_v = np.zeros(2)
        pi_step.py_func(
            self.params, self.state, measurement.t_s, measurement.q_m, measurement.dq_m_s, reference.row(), u_v
        )
        return u_v

    def state_for_logging(self):  # noqa: ANN201
        return log_values(self.compiled, self.params, self.state)


@pytest.mark.skipif(not compiled_available(), reason="no compiled backend on this machine")
def test_a_plugin_with_a_compiled_step_runs_compiled_and_bit_identical():
    assert compiled_step_of(PI()) is PI.compiled
    assert isinstance(loop_needs_compiling(PI()), bool)
    runs = {}
    for backend in ("compiled", "reference"):
        controller = PI()
        runs[backend] = (simulate(Plant(), circle(), TimingLaw(2.0), controller, 0.2, backend=backend), controller)
    (a, ca), (b, cb) = runs["compiled"], runs["reference"]
    assert ca.updates == 0 and cb.updates == a.t_s.size  # the compiled run never called update()
    for name in ("q_m", "q_meas_m", "e_m", "eps_n_m", "eps_c_m", "u_v"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert list(a.controller_state) == list(b.controller_state) == ["integral_m_s", "samples"]
    assert a.controller_state["integral_m_s"].shape == (a.t_s.size, 2)
    assert a.controller_state["samples"].shape == (a.t_s.size,)
    for key in a.controller_state:
        np.testing.assert_array_equal(a.controller_state[key], b.controller_state[key], err_msg=key)
    np.testing.assert_array_equal(a.controller_state["samples"], np.arange(1, a.t_s.size + 1))
    # The compiled run leaves the controller object where the reference run leaves it.
    np.testing.assert_array_equal(ca.state.integral_m_s, cb.state.integral_m_s)
    assert np.abs(ca.state.integral_m_s).max() > 0.0
    assert not np.allclose(a.u_v, 0.0)
