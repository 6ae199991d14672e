"""The amplifier's plant effects (docs/equations.md, "The amplifier"): a computation delay of n samples and a
first-order current loop, each against its analytic result, in the kernel and in the loop on both backends."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import PD
from gantry_twin.numerics.jit import reference
from gantry_twin.plant.effects import Amplifier, amplifier_output
from gantry_twin.scenario import ScenarioError, build, validate_data

TS_S = 2e-4


def drive(amplifier: Amplifier, commands: np.ndarray) -> np.ndarray:
    """The amplifier's output, sample by sample, for commands (k, 2), through the plain-Python kernel."""
    step = reference(amplifier_output)
    state = amplifier.state()
    gain = amplifier.current_gain(TS_S)
    return np.array([[step(amplifier.delay_samples, gain, state, i, u[i]) for i in range(2)] for u in commands])


@pytest.mark.parametrize("n", [1, 2, 5])
def test_a_delay_of_n_samples_shifts_the_command_by_exactly_n(n):
    commands = np.random.default_rng(n).normal(size=(200, 2))
    out = drive(Amplifier(delay_samples=n), commands)
    np.testing.assert_array_equal(out[n:], commands[:-n])
    np.testing.assert_array_equal(out[:n], 0.0)  # the DAC's 0 V before the first delayed command


def test_the_current_loops_step_response_is_one_minus_exp():
    tau = 1.5e-4
    k = np.arange(400)
    out = drive(Amplifier(current_tau_s=tau), np.ones((k.size, 2)))
    exact = 1.0 - np.exp(-(k + 1) * TS_S / tau)  # 1 - exp(-t / tau) sampled at the end of each sample
    np.testing.assert_allclose(out[:, 0], exact, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out[:, 1], exact, rtol=0, atol=1e-12)
    # with a delay too: the same response, n samples later
    late = drive(Amplifier(delay_samples=3, current_tau_s=tau), np.ones((k.size, 2)))
    np.testing.assert_allclose(late[3:, 0], exact[:-3], rtol=0, atol=1e-12)


def test_off_is_the_command_itself():
    commands = np.random.default_rng(0).normal(size=(50, 2))
    np.testing.assert_array_equal(drive(Amplifier(), commands), commands)
    assert Amplifier().current_gain(TS_S) == 1.0


class Recorder(PD):
    """PD that also reads, at each update, the motor input MuJoCo held during the previous sample."""

    def __init__(self, plant: Plant) -> None:
        super().__init__()
        self.plant, self.applied, self.commands = plant, [], []

    def update(self, measurement, reference):  # noqa: ANN001, ANN201
        self.applied.append(self.plant.data.ctrl[self.plant.motor_index].copy())
        u = np.asarray(super().update(measurement, reference), dtype=float)
        self.commands.append(u.copy())
        return u


def test_in_the_loop_the_motor_gets_the_command_of_n_samples_ago_through_the_current_loop():
    n, tau = 2, 2e-4
    plant = Plant(amplifier=Amplifier(delay_samples=n, current_tau_s=tau))
    controller = Recorder(plant)
    trace = simulate(plant, circle(), TimingLaw(2.0), controller, 0.02, backend="reference")
    applied = np.array(controller.applied[1:])  # the input of samples 0 .. K-2
    u = trace.u_v[: applied.shape[0]]
    assert np.abs(u).max() > 0.05  # the loop commands something
    a = -math.expm1(-TS_S / tau)
    current = np.zeros(2)
    expected = []
    for k in range(applied.shape[0]):
        late = u[k - n] if k >= n else np.zeros(2)
        current = current + a * (late - current)
        expected.append(current.copy())
    np.testing.assert_allclose(applied, np.array(expected), rtol=0, atol=1e-12)


def test_both_backends_agree_with_the_amplifier_on():
    def run(backend):  # noqa: ANN001, ANN202
        plant = Plant(amplifier=Amplifier(delay_samples=1, current_tau_s=1.5e-4))
        return simulate(plant, circle(), TimingLaw(2.0), PD(), 0.2, backend=backend)

    a, b = run("compiled"), run("reference")
    assert np.abs(a.u_v - b.u_v).max() < 1e-9
    for name in ("q_m", "q_meas_m", "eps_c_m"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    # the amplifier changes the run (the comparison is not of two runs without it)
    c = simulate(Plant(), circle(), TimingLaw(2.0), PD(), 0.2, backend="compiled")
    assert np.abs(a.q_m - c.q_m).max() > 1e-9


def test_a_scenario_sets_them_with_their_ranges():
    built = build(validate_data({"plant": {"amplifier": {"delay_samples": 1, "current_tau_s": 1e-4}}}, "s.yaml"), "s")
    assert built.plant.amplifier == Amplifier(1, 1e-4)
    with pytest.raises(ScenarioError, match=r"plant\.amplifier\.delay_samples.*\[0, 10\]"):
        validate_data({"plant": {"amplifier": {"delay_samples": 11}}}, "s.yaml")
    with pytest.raises(ScenarioError, match=r"plant\.amplifier\.current_tau_s"):
        validate_data({"plant": {"amplifier": {"current_tau_s": -1}}}, "s.yaml")
