"""The compiled loop against its uncompiled reference, and the pieces the compiled loop relies on.

The compiled backend runs the same kernels as the reference backend, so the
traces are expected to agree to the last bit; the assertions use a
1e-9 V bound on u and compare every other trace array exactly.
"""

from __future__ import annotations

import types

import mujoco
import numpy as np
import pytest

from gantry_twin import Plant, SensingConfig, TimingLaw, circle, paper_ellipse, simulate
from gantry_twin.controllers import DARC, DIARC, DRC, PD, RECOMMENDED_ESTIMATOR, create
from gantry_twin.controllers.arc import diarc_step
from gantry_twin.loop.trace import SimulationError
from gantry_twin.numerics.estimation import LeastSquaresSettings, least_squares_step
from gantry_twin.numerics.jit import reference
from gantry_twin.numerics.linalg import EIGENVALUE_TOLERANCE, largest_eigenvalue, largest_eigenvalue_exact

U_TOLERANCE_V = 1e-9
TRACE_FIELDS = ("q_m", "q_meas_m", "e_m", "eps_n_m", "eps_c_m", "u_v")


def run_both(make, duration_s, path=None, **kwargs):  # noqa: ANN001, ANN201
    out = {}
    for backend in ("compiled", "reference"):
        controller = make()
        trace = simulate(Plant(), path or circle(), TimingLaw(2.0), controller, duration_s, backend=backend, **kwargs)
        out[backend] = (trace, controller)
    return out["compiled"], out["reference"]


def assert_same_trace(a, b):  # noqa: ANN001, ANN201
    assert np.abs(a.u_v - b.u_v).max() < U_TOLERANCE_V
    for name in TRACE_FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.controller_state.keys() == b.controller_state.keys()
    for key in a.controller_state:
        assert a.controller_state[key].shape == b.controller_state[key].shape
        np.testing.assert_array_equal(a.controller_state[key], b.controller_state[key], err_msg=key)
    assert a.filled == b.filled == a.t_s.size


@pytest.mark.slow
def test_diarc_compiled_equals_reference_to_the_controller_state():
    (a, ca), (b, cb) = run_both(DIARC, 0.5)  # 2 s of every scenario on both backends: test_pinned_traces
    assert_same_trace(a, b)
    assert set(a.controller_state) == {"theta_hat", "dc_hat", "gamma_diag", "gamma_lambda_max"}
    assert a.controller_state["theta_hat"].shape == (a.t_s.size, 8)
    assert a.controller_state["gamma_lambda_max"].shape == (a.t_s.size,)
    assert np.abs(a.controller_state["theta_hat"] - b.controller_state["theta_hat"]).max() < 1e-12
    # The run moved the estimates, so agreement is not trivially about constants.
    assert np.abs(a.controller_state["theta_hat"][-1] - a.controller_state["theta_hat"][0]).max() > 1e-3
    # The compiled run leaves the controller object where the reference run leaves it.
    for x, y in zip(ca.state.estimator[:6], cb.state.estimator[:6], strict=True):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(ca.theta, cb.theta)
    np.testing.assert_array_equal(ca.dc, cb.dc)
    np.testing.assert_array_equal(ca.estimator.gamma, cb.estimator.gamma)


@pytest.mark.parametrize("name", ["drc", "darc", "pd"])
def test_other_controllers_compiled_equals_reference(name):
    (a, ca), (b, cb) = run_both(lambda: create(name), 0.5, path=paper_ellipse())
    assert_same_trace(a, b)
    if name == "darc":
        np.testing.assert_array_equal(ca.theta, cb.theta)
        assert np.abs(a.controller_state["theta_hat"][-1] - a.controller_state["theta_hat"][0]).max() > 1e-4


def test_ideal_sensing_and_disturbance_agree():
    def step(t):  # noqa: ANN001, ANN202
        d = np.zeros((t.size, 2))
        d[(t >= 0.1) & (t < 0.3), 1] = 0.6
        return d

    (a, _), (b, _) = run_both(
        lambda: DIARC(estimator=RECOMMENDED_ESTIMATOR), 0.4, sensing=SensingConfig.ideal(), disturbance=step
    )
    assert_same_trace(a, b)


def test_plant_alone_matches_a_plain_mj_step_loop():
    """Zero-gain PD: u = 0, the plant driven by the disturbance inputs only."""
    rng = np.random.default_rng(3)

    def disturbance(t):  # noqa: ANN001, ANN202
        return rng.normal(0.0, 2.0, (t.size, 2))

    zero = dict(kp_v_m=(0.0, 0.0), kd_v_s_m=(0.0, 0.0), kv_v_s_m=(0.0, 0.0), ka_v_s2_m=(0.0, 0.0))
    inputs = disturbance(np.zeros(1500))
    traces = {
        b: simulate(Plant(), circle(), TimingLaw(2.0), PD(**zero), 0.3, disturbance=lambda t: inputs, backend=b)
        for b in ("compiled", "reference")
    }
    np.testing.assert_array_equal(traces["compiled"].q_m, traces["reference"].q_m)
    assert np.all(traces["compiled"].u_v == 0.0)
    # Independent loop: same start, the same inputs, mujoco.mj_step from Python.
    plant = Plant()
    ref = traces["reference"]
    plant.reset(ref.q_d_m[0], circle().derivatives(np.zeros(1))[1][0] * 2.0)
    q = np.empty_like(ref.q_m)
    for k in range(q.shape[0]):
        q[k] = plant.q_m
        plant.data.ctrl[plant.motor_index] = 0.0
        plant.data.ctrl[plant.disturbance_index] = inputs[k]
        mujoco.mj_step(plant.model, plant.data)
    np.testing.assert_array_equal(traces["compiled"].q_m, q)
    assert np.abs(q[-1] - q[0]).max() > 1e-4  # the inputs moved the plant


class _Poison:
    """Observer that corrupts the plant's position after the first chunk (a sensor failure)."""

    def __init__(self, plant: Plant) -> None:
        self.plant = plant

    def on_start(self, run, trace):  # noqa: ANN001, ANN201
        pass

    def on_chunk(self, trace, start, stop):  # noqa: ANN001, ANN201
        self.plant.data.qpos[self.plant.qpos_index[1]] = np.nan

    def on_end(self, trace):  # noqa: ANN001, ANN201
        pass


@pytest.mark.parametrize("backend", ["compiled", "reference"])
def test_nan_measurement_stops_both_backends(backend):
    plant = Plant()
    with pytest.raises(SimulationError, match=r"non-finite measurement at t = 0\.0100 s"):
        simulate(
            plant, circle(), TimingLaw(2.0), DIARC(), 0.05, observers=[_Poison(plant)], chunk_s=0.01, backend=backend
        )


@pytest.mark.parametrize("backend", ["compiled", "reference"])
def test_nan_command_stops_both_backends(backend):
    theta = (0.1, 0.5, 0.5, 0.7, 0.1, 0.15, float("nan"), 0.0)
    with pytest.raises(SimulationError, match=r"controller returned .*nan.* at t = 0\.0000 s"):
        simulate(Plant(), circle(), TimingLaw(2.0), DRC(theta=theta), 0.01, backend=backend)


def test_plugin_controller_uses_the_python_loop():
    class Zero:
        def reset(self, context):  # noqa: ANN001, ANN201
            pass

        def update(self, measurement, reference):  # noqa: ANN001, ANN201
            return np.zeros(2)

        def state_for_logging(self):  # noqa: ANN201
            return {"k": np.ones(3)}

    trace = simulate(Plant(), circle(), TimingLaw(2.0), Zero(), 0.01)
    assert np.all(trace.u_v == 0.0) and trace.controller_state["k"].shape == (50, 3)
    with pytest.raises(ValueError, match="backend 'compiled' runs only controllers that offer a compiled step"):
        simulate(Plant(), circle(), TimingLaw(2.0), Zero(), 0.01, backend="compiled")
    with pytest.raises(ValueError, match="backend must be"):
        simulate(Plant(), circle(), TimingLaw(2.0), DRC(), 0.01, backend="fast")


def test_reference_is_uncompiled_python():
    ref = reference(diarc_step)
    assert isinstance(ref, types.FunctionType)
    assert isinstance(ref.__globals__["_law"], types.FunctionType)
    assert isinstance(ref.__globals__["_law"].__globals__["arc_law"], types.FunctionType)
    assert isinstance(ref.__globals__["_law"].__globals__["arc_law"].__globals__["error_gains"], types.FunctionType)


def _spd_with_top_pair(rng, gap):  # noqa: ANN001, ANN202
    q, _ = np.linalg.qr(rng.normal(size=(8, 8)))
    values = np.sort(rng.uniform(1.0, 100.0, 8))
    values[-2] = values[-1] * (1.0 - gap)
    return (q * values) @ q.T, values[-1]


@pytest.mark.parametrize("gap", [0.5, 1e-3, 1e-9, 0.0])
def test_largest_eigenvalue_against_eigvalsh(gap):
    rng = np.random.default_rng(11)
    for _ in range(20):
        a, _ = _spd_with_top_pair(rng, gap)
        a = 0.5 * (a + a.T)
        exact = np.linalg.eigvalsh(a)[-1]
        v = np.zeros((2, 8))
        v[0, 0] = v[1, 1] = 1.0
        scratch = (np.zeros((2, 8)), np.zeros((8, 8)), np.zeros(8), np.zeros(8))
        got = largest_eigenvalue(a, v, *scratch)
        assert exact * (1 - 1e-13) <= got * (1 + EIGENVALUE_TOLERANCE) and got <= exact * (1 + 1e-13)
        assert abs(largest_eigenvalue_exact(a, np.inf, *scratch[1:]) - exact) <= 1e-12 * exact
        # Warm start on a slightly changed matrix, as in the loop.
        a2 = a - 1e-4 * np.outer(a[:, 0], a[:, 0]) / a[0, 0]
        got2 = largest_eigenvalue(a2, v, *scratch)
        exact2 = np.linalg.eigvalsh(a2)[-1]
        assert exact2 * (1 - EIGENVALUE_TOLERANCE - 1e-13) <= got2 <= exact2 * (1 + 1e-13)


def test_least_squares_lambda_max_over_many_steps():
    rng = np.random.default_rng(5)
    settings = LeastSquaresSettings()
    gamma = np.diag(np.asarray(settings.gamma0_diag, dtype=float))
    theta = np.array([0.1, 0.55, 0.4, 0.6, 0.1, 0.15, 0.0, 0.0])
    lower = np.array([0.05, 0.45, 0.35, 0.5, 0.05, 0.08, -0.5, -1.0])
    upper = np.array([0.20, 0.60, 0.55, 0.8, 0.15, 0.25, 0.5, 1.0])
    for _ in range(300):
        g = np.zeros((8, 2))
        g[[0, 2, 4, 6], 0] = rng.normal(size=4) * [5, 0.3, 1, 1]
        g[[1, 3, 5, 7], 1] = rng.normal(size=4) * [5, 0.3, 1, 1]
        lam = least_squares_step(theta, gamma, g, rng.normal(size=2), settings, lower, upper, 2e-4)
        exact = np.linalg.eigvalsh(gamma)[-1]
        assert abs(lam - exact) <= 2 * EIGENVALUE_TOLERANCE * exact
        np.testing.assert_array_equal(gamma, gamma.T)
        assert np.all((theta >= lower) & (theta <= upper))


def test_logged_lambda_max_matches_final_gamma():
    controller = DIARC()
    trace = simulate(Plant(), circle(), TimingLaw(2.0), controller, 0.5)
    exact = np.linalg.eigvalsh(controller.estimator.gamma)[-1]
    logged = trace.controller_state["gamma_lambda_max"][-1]
    assert abs(logged - exact) <= 2 * EIGENVALUE_TOLERANCE * exact
    np.testing.assert_array_equal(trace.controller_state["gamma_diag"][-1], np.diag(controller.estimator.gamma))


def test_plant_changes_compiled_equals_reference_and_restore_the_model():
    """Every kind of change at once (drift, pick-up, cogging, spike, hold, velocity noise): same bits."""
    from gantry_twin.plant.faults import (
        CoggingRipple,
        EncoderGlitch,
        FrictionDrift,
        PayloadChange,
        PlantChanges,
        VelocityNoise,
    )

    changes = PlantChanges(
        friction_drift=(FrictionDrift("y", 0.1, 0.3, viscous_to_v_s_m=0.91, coulomb_to_v=0.2),),
        payload_change=(PayloadChange(0.2, 5.0),),
        cogging=(CoggingRipple("x", 0.05, 0.016), CoggingRipple("y", 0.05, 0.016, 0.3)),
        encoder_glitch=(EncoderGlitch("spike", 0.15, "x"), EncoderGlitch("hold", 0.25, samples=3)),
        velocity_noise=VelocityNoise((1e-3, 2e-3), seed=1),
    )
    out = {}
    for backend in ("compiled", "reference"):
        plant = Plant(payload_body=True)
        before = (plant.model.dof_damping.copy(), plant.model.body_mass.copy())
        out[backend] = simulate(
            plant,
            circle(),
            TimingLaw(2.0),
            DIARC(estimator=RECOMMENDED_ESTIMATOR),
            0.4,
            backend=backend,
            changes=changes,
        )
        np.testing.assert_array_equal(plant.model.dof_damping, before[0])
        np.testing.assert_array_equal(plant.model.body_mass, before[1])
    a, b = out["compiled"], out["reference"]
    assert_same_trace(a, b)
    np.testing.assert_array_equal(a.true_theta_t, b.true_theta_t)
    # The changes acted: the spike and the hold are in the measurement the controller saw.
    k = int(round(0.15 / a.sample_period_s))
    assert abs((a.q_meas_m[k, 0] - a.q_m[k, 0]) - 50e-6) < 1e-6
    h = int(round(0.25 / a.sample_period_s))
    np.testing.assert_array_equal(a.q_meas_m[h : h + 3], np.repeat(a.q_meas_m[h - 1 : h], 3, axis=0))
    assert a.true_theta_t[-1, 3] == pytest.approx(0.91) and a.true_theta_t[-1, 0] == pytest.approx(0.12 + 5 / 69)


def test_loop_needs_compiling_asks_the_cache_for_the_controllers_chunk_kernel(monkeypatch):
    """A compile is announced when numba's cache lacks this controller's chunk kernel (the cache check itself:
    tests/test_compiling.py); DRC, DARC and DIARC share one, and so does a subclass with the same compiled step."""
    import importlib

    from gantry_twin.controllers.base import compiled_step_of
    from gantry_twin.loop.simulate import chunk_kernel, compiled_available, loop_needs_compiling

    if not compiled_available():
        pytest.skip("no compiled backend on this machine")
    monkeypatch.setattr(
        importlib.import_module("gantry_twin.loop.simulate"),
        "is_cached",
        lambda function: function is chunk_kernel(DIARC.compiled),
    )
    assert not loop_needs_compiling(DIARC())
    assert loop_needs_compiling(PD())  # its own chunk kernel is not cached
    assert not loop_needs_compiling(DRC()) and not loop_needs_compiling(DARC())  # DIARC's kernel: one ARC loop
    assert chunk_kernel(DRC.compiled) is chunk_kernel(DIARC.compiled) is not chunk_kernel(PD.compiled)

    class MyDIARC(DIARC):  # the same compiled step: the same kernel
        pass

    class Overridden(DIARC):  # update() overridden: the Python loop, nothing to compile
        def update(self, measurement, reference):  # noqa: ANN001, ANN201
            return super().update(measurement, reference)

    assert not loop_needs_compiling(MyDIARC()) and not loop_needs_compiling(Overridden())
    assert compiled_step_of(MyDIARC()) is DIARC.compiled and compiled_step_of(Overridden()) is None


def test_a_subclass_overriding_update_runs_in_the_python_loop():
    """The compiled loop would ignore an overridden update(); such a subclass must get the Python loop."""
    calls = []

    class Counting(PD):
        def update(self, measurement, reference):  # noqa: ANN001, ANN201
            calls.append(measurement.t_s)
            return super().update(measurement, reference)

    simulate(Plant(), circle(), TimingLaw(2.0), Counting(), 0.01)
    assert len(calls) == 50
    with pytest.raises(ValueError, match="does not"):
        simulate(Plant(), circle(), TimingLaw(2.0), Counting(), 0.01, backend="compiled")
