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
from gantry_twin.loop.simulate import compiled_available, loop_needs_compiling


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


@numba.njit
def allocating_step(params, state, t_s, q_m, dq_m_s, ref, u_v):
    e = np.empty(2)  # an array allocated every sample: the loop needs numba's reference counting for this step
    for i in range(2):
        e[i] = q_m[i] - ref[REF_Q + i]
    for i in range(2):
        de = dq_m_s[i] - ref[REF_DQ + i]
        u_v[i] = min(max(-params.kp_v_m * e[i] - params.kd_v_s_m * de, -params.u_max_v[i]), params.u_max_v[i])


class AllocatingPD(PI):
    compiled = CompiledStep(allocating_step)

    def update(self, measurement, reference):  # noqa: ANN001, ANN201
        self.updates += 1
        u_v = np.zeros(2)
        allocating_step.py_func(
            self.params, self.state, measurement.t_s, measurement.q_m, measurement.dq_m_s, reference.row(), u_v
        )
        return u_v

    def state_for_logging(self):  # noqa: ANN201
        return {}


@pytest.mark.skipif(not compiled_available(), reason="no compiled backend on this machine")
def test_a_step_that_allocates_runs_compiled_with_reference_counting():
    """The loop compiles without numba's reference counting; a step that allocates gets a loop compiled with it."""
    from gantry_twin.loop.sample import chunk_kernel

    controller = AllocatingPD()
    compiled = simulate(Plant(), circle(), TimingLaw(2.0), controller, 0.05, backend="compiled")
    reference = simulate(Plant(), circle(), TimingLaw(2.0), AllocatingPD(), 0.05, backend="reference")
    assert controller.updates == 0
    np.testing.assert_array_equal(compiled.u_v, reference.u_v)
    np.testing.assert_array_equal(compiled.q_m, reference.q_m)
    assert chunk_kernel(AllocatingPD.compiled, nrt=True).signatures  # the loop that ran
    assert not chunk_kernel(AllocatingPD.compiled).signatures  # the one without reference counting did not compile


SHARED = """
import json, sys
sys.path.insert(0, {root!r})
from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import PD
from gantry_twin.controllers.base import compiled_step_of
from gantry_twin.loop.sample import chunk_kernel, measure_sample, record_and_step, record_log
controller = PD()
if sys.argv[1] == "plugin":
    from tests.test_compiled_plugins import PI
    controller = PI()
simulate(Plant(), circle(), TimingLaw(2.0), controller, 0.01, backend="compiled")
stats = {{k.__name__: [sum(k.stats.cache_hits.values()), sum(k.stats.cache_misses.values())]
         for k in (measure_sample, record_and_step, record_log, chunk_kernel(compiled_step_of(controller)))}}
print(json.dumps(stats))
"""


@pytest.mark.slow
@pytest.mark.skipif(not compiled_available(), reason="no compiled backend on this machine")
def test_a_plugin_compiles_only_its_own_loop_the_shared_kernels_load_from_the_cache(tmp_path):
    """After any built-in loop has run on this install, a plug-in's first run compiles its chunk (with its step
    inlined) and loads the plant's half of the loop from numba's cache instead of compiling it again."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = str(Path(__file__).resolve().parent.parent)
    env = {**os.environ, "PYTHONPATH": os.path.join(root, "src"), "NUMBA_CACHE_DIR": str(tmp_path / "numba")}

    def run(which: str) -> dict:
        code = SHARED.format(root=root)
        out = subprocess.run([sys.executable, "-c", code, which], env=env, capture_output=True, text=True, check=True)
        return json.loads(out.stdout.strip().splitlines()[-1])

    first = run("pd")
    assert all(misses == 1 for _, misses in first.values()), first  # an empty cache: everything compiles
    plugin = run("plugin")
    shared = {name: value for name, value in plugin.items() if not name.startswith("run_chunk")}
    assert len(shared) == 3 and all(v == [1, 0] for v in shared.values()), plugin  # loaded, not compiled
    (chunk,) = (value for name, value in plugin.items() if name.startswith("run_chunk"))
    assert chunk == [0, 1]  # the plug-in's own loop compiles
