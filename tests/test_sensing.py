"""Encoder model (docs/equations.md, sensing): 0.5 um counts, velocity by backward difference."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gantry_twin import Plant, TimingLaw, Trace, circle, create, simulate
from gantry_twin.plant.sensing import Encoder, SensingConfig, quantize

TS_S = 0.2e-3
RES_M = 0.5e-6
positions = st.floats(min_value=-0.3, max_value=0.3, allow_nan=False, allow_infinity=False)
velocities = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False, allow_infinity=False)


class Recorder:
    """A plug-in wrapping the built-in PD that keeps every measurement the controller is given."""

    def __init__(self) -> None:
        self.inner = create("pd")
        self.positions: list[np.ndarray] = []
        self.velocities: list[np.ndarray] = []

    def reset(self, context):  # noqa: ANN001, ANN201
        self.inner.reset(context)

    def update(self, measurement, reference):  # noqa: ANN001, ANN201
        self.positions.append(np.array(measurement.q_m, dtype=float))
        self.velocities.append(np.array(measurement.dq_m_s, dtype=float))
        return self.inner.update(measurement, reference)

    def state_for_logging(self):  # noqa: ANN201
        return {}


def slow_circle_run(controller) -> Trace:  # noqa: ANN001
    """1 s on a 1 mm circle at 1 rad/s (1 mm/s: 0.2 um per sample, both axes move), default sensing."""
    return simulate(Plant(), circle(radius_m=1e-3), TimingLaw(1.0), controller, 1.0)


def test_resolution_is_half_a_micrometre() -> None:
    """In a real run the recorded reading is the true position rounded to 0.5 um (docs/equations.md, sensing),
    and a carriage moving less than a count per sample steps one count at a time."""
    trace = slow_circle_run(create("pd"))
    expected = np.floor(trace.q_m / RES_M + 0.5) * RES_M  # nearest count, written independently of sensing.quantize
    np.testing.assert_allclose(trace.q_meas_m, expected, rtol=0, atol=1e-12)
    assert np.abs(trace.q_meas_m - trace.q_m).max() <= RES_M / 2 * (1 + 1e-9)
    steps = np.diff(trace.q_meas_m, axis=0)
    moved = steps != 0.0
    np.testing.assert_allclose(np.abs(steps[moved]), RES_M, rtol=1e-9)
    # X travels 0.84 mm (1680 counts) and Y 0.46 mm (920 counts), neither more than a count per sample.
    assert moved[:, 0].sum() >= 1600 and moved[:, 1].sum() >= 850


def test_controller_sees_whole_counts_and_velocity_in_counts_per_sample() -> None:
    """What a controller is given in a real run: the recorded reading, and velocity in steps of 0.5 um / 0.2 ms."""
    recorder = Recorder()
    trace = slow_circle_run(recorder)
    positions, velocities = np.array(recorder.positions), np.array(recorder.velocities)
    np.testing.assert_array_equal(positions, trace.q_meas_m)
    counts_per_sample = velocities * TS_S / RES_M
    np.testing.assert_allclose(counts_per_sample, np.round(counts_per_sample), rtol=0, atol=1e-6)
    np.testing.assert_allclose(velocities[1:], np.diff(positions, axis=0) / TS_S, rtol=1e-12, atol=1e-12)
    assert set(np.unique(np.round(counts_per_sample[1:, 0]))) == {0.0, 1.0}  # 1 mm/s: 0 or 1 count per sample


@given(positions, positions)
def test_quantised_positions_are_whole_counts_within_half_a_count(x: float, y: float) -> None:
    q = np.array([x, y])
    measured = quantize(q, RES_M)
    counts = measured / RES_M
    np.testing.assert_allclose(counts, np.round(counts), rtol=0, atol=1e-6)
    assert np.all(np.abs(measured - q) <= RES_M / 2 * (1 + 1e-9))


def test_quantisation_staircase() -> None:
    q = np.array([0.0, 0.24e-6, 0.26e-6, 0.74e-6, 0.76e-6, -0.26e-6, 1.0e-3 + 0.1e-6])
    expected = np.array([0.0, 0.0, 0.5e-6, 0.5e-6, 1.0e-6, -0.5e-6, 1.0e-3])
    np.testing.assert_allclose(quantize(q, RES_M), expected, rtol=0, atol=1e-15)


def test_velocity_is_backward_difference_of_measured_positions() -> None:
    encoder = Encoder(SensingConfig(), TS_S)
    rng = np.random.default_rng(7)
    q = np.cumsum(rng.normal(0, 20e-6, (50, 2)), axis=0)
    encoder.reset(q[0], np.zeros(2))
    previous = quantize(q[0], RES_M)
    for k in range(1, q.shape[0]):
        position, velocity = encoder.measure(q[k], np.array([99.0, -99.0]))  # true velocity is ignored
        np.testing.assert_allclose(position, quantize(q[k], RES_M), rtol=0, atol=1e-15)
        np.testing.assert_allclose(velocity, (position - previous) / TS_S, rtol=1e-12)
        previous = position


def test_velocity_resolution_is_one_count_per_sample() -> None:
    """A slow ramp: each velocity reading is a whole number of counts per sample."""
    encoder = Encoder(SensingConfig(), TS_S)
    v_true = np.array([0.4, -0.013])  # m/s
    encoder.reset(np.zeros(2), v_true)
    readings = []
    for k in range(2000):  # the first reading is at q = 0, the reset position
        readings.append(encoder.measure(v_true * k * TS_S, v_true)[1])
    readings = np.array(readings)
    steps = readings * TS_S / RES_M
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    # Mean is the true velocity; each reading within one count per sample (2.5 mm/s).
    np.testing.assert_allclose(readings.mean(axis=0), v_true, atol=RES_M / TS_S / 2000 * 2)
    assert np.all(np.abs(readings - v_true) <= RES_M / TS_S * (1 + 1e-9))


@given(positions, positions, velocities, velocities)
def test_ideal_sensing_passes_through(x: float, y: float, vx: float, vy: float) -> None:
    encoder = Encoder(SensingConfig.ideal(), TS_S)
    q, dq = np.array([x, y]), np.array([vx, vy])
    encoder.reset(q, dq)
    position, velocity = encoder.measure(q, dq)
    np.testing.assert_array_equal(position, q)
    np.testing.assert_array_equal(velocity, dq)


def test_difference_without_quantisation_is_exact_on_a_ramp() -> None:
    encoder = Encoder(SensingConfig(quantize=False), TS_S)
    v = np.array([0.4, -0.2])
    encoder.reset(np.array([0.1, 0.0]), v)
    for k in range(5):
        position, velocity = encoder.measure(np.array([0.1, 0.0]) + v * k * TS_S, np.zeros(2))
        np.testing.assert_allclose(velocity, v, rtol=1e-9)
        np.testing.assert_allclose(position, np.array([0.1, 0.0]) + v * k * TS_S, rtol=0, atol=1e-18)


@pytest.mark.parametrize("config", [SensingConfig(), SensingConfig(quantize=False)])
@given(positions, positions, velocities, velocities)
def test_reset_makes_first_velocity_the_initial_velocity(
    config: SensingConfig, x: float, y: float, vx: float, vy: float
) -> None:
    """As if the machine had been moving at dq before t = 0 (the on_path start)."""
    encoder = Encoder(config, TS_S)
    q, dq = np.array([x, y]), np.array([vx, vy])
    encoder.reset(q, dq)
    _, velocity = encoder.measure(q, dq)
    tolerance = RES_M / TS_S if config.quantize else 1e-9
    assert np.all(np.abs(velocity - dq) <= tolerance * (1 + 1e-9))
