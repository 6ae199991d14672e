"""Encoder model of control-spec section 2: 0.5 um counts, velocity by backward difference."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gantry_twin.sensing import ENCODER_RESOLUTION_M, Encoder, SensingConfig, quantize

TS_S = 0.2e-3
RES_M = 0.5e-6
positions = st.floats(min_value=-0.3, max_value=0.3, allow_nan=False, allow_infinity=False)
velocities = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False, allow_infinity=False)


def test_resolution_is_half_a_micrometre() -> None:
    assert ENCODER_RESOLUTION_M == 0.5e-6
    assert SensingConfig().resolution_m == 0.5e-6
    assert SensingConfig().quantize and SensingConfig().velocity_by_difference


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
