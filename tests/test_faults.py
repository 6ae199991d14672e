"""Plant-change schedules (gantry_twin.plant.faults) against hand computation and the compiled model."""

from __future__ import annotations

import numpy as np
import pytest

from gantry_twin import Payload, Plant
from gantry_twin.plant.faults import (
    CoggingRipple,
    EncoderGlitch,
    FrictionDrift,
    PayloadChange,
    PlantChanges,
    VelocityNoise,
)

TS = 2.0e-4


@pytest.fixture(scope="module")
def plant():
    return Plant()


def times(duration_s: float) -> np.ndarray:
    return np.arange(int(round(duration_s / TS))) * TS


def test_viscous_drift_schedule_is_the_hand_ramp(plant):
    changes = PlantChanges(friction_drift=(FrictionDrift("y", 20.0, 80.0, viscous_to_v_s_m=0.91),))
    t = np.array([0.0, 19.9, 20.0, 35.0, 50.0, 80.0, 90.0])
    damping = changes.damping_n_s_m(plant, t)
    # By hand: B2 = 0.7 + 0.21 (t - 20) / 60 V/(m/s), times the 69 N/V gear; X keeps 34.5 N s/m.
    b2 = np.array([0.7, 0.7, 0.7, 0.7 + 0.21 * 15 / 60, 0.7 + 0.21 * 30 / 60, 0.91, 0.91])
    np.testing.assert_allclose(damping[:, 1], b2 * 69.0, rtol=1e-12)
    np.testing.assert_allclose(damping[:, 0], 34.5, rtol=1e-12)
    np.testing.assert_allclose(changes.frictionloss_n(plant, t), np.tile([6.9, 10.35], (t.size, 1)), rtol=1e-12)


def test_coulomb_drift_from_a_given_start_value(plant):
    changes = PlantChanges(friction_drift=(FrictionDrift("x", 1.0, 3.0, coulomb_from_v=0.2, coulomb_to_v=0.4),))
    t = np.array([0.0, 1.0, 2.0, 2.5, 3.0, 4.0])
    np.testing.assert_allclose(
        changes.frictionloss_n(plant, t)[:, 0], np.array([0.2, 0.2, 0.3, 0.35, 0.4, 0.4]) * 69.0, rtol=1e-12
    )
    np.testing.assert_allclose(changes.damping_n_s_m(plant, t), np.tile([34.5, 48.3], (t.size, 1)), rtol=1e-12)


def test_payload_schedule_pick_up_and_drop(plant):
    changes = PlantChanges(payload_change=(PayloadChange(20.0, 5.0), PayloadChange(40.0, 0.0)))
    t = np.array([0.0, 19.9998, 20.0, 30.0, 39.9998, 40.0, 50.0])
    np.testing.assert_array_equal(changes.payload_mass_kg(plant, t), [0, 0, 5, 5, 5, 0, 0])


def test_true_parameters_over_time_match_a_plant_built_with_the_new_mass(plant):
    changes = PlantChanges(
        payload_change=(PayloadChange(20.0, 5.0), PayloadChange(40.0, 2.5)),
        friction_drift=(FrictionDrift("y", 20.0, 80.0, viscous_to_v_s_m=0.91),),
    )
    t = np.array([10.0, 30.0, 50.0])
    theta = changes.true_parameters_over_time(plant, t)
    for row, mass in zip(theta, (0.0, 5.0, 2.5), strict=True):
        expected = Plant(Payload(mass)).true_parameters()
        np.testing.assert_allclose(row[[0, 1, 2, 4, 5, 6, 7]], expected[[0, 1, 2, 4, 5, 6, 7]], rtol=1e-12, atol=0)
    np.testing.assert_allclose(theta[:, 3], 0.7 + 0.21 * np.clip((t - 20.0) / 60.0, 0.0, 1.0), rtol=1e-12)


def test_true_parameters_start_from_a_loaded_plant():
    loaded = Plant(Payload(5.0))
    changes = PlantChanges(payload_change=(PayloadChange(1.0, 0.0),))
    theta = changes.true_parameters_over_time(loaded, np.array([0.0, 2.0]))
    np.testing.assert_allclose(theta[0], loaded.true_parameters(), rtol=1e-12)
    np.testing.assert_allclose(theta[1], Plant().true_parameters(), rtol=1e-12)


def test_no_changes_give_the_plant_itself(plant):
    t = times(0.01)
    theta = PlantChanges().true_parameters_over_time(plant, t)
    np.testing.assert_allclose(theta, np.tile(plant.true_parameters(), (t.size, 1)), rtol=1e-12)
    assert PlantChanges().empty


def test_glitch_schedules():
    changes = PlantChanges(
        encoder_glitch=(
            EncoderGlitch("spike", 0.0010, axis="y", offset_m=50e-6),
            EncoderGlitch("hold", 0.0020, samples=3),
        )
    )
    t = times(0.003)  # 15 samples, 0 .. 2.8 ms
    offset = changes.position_offset_m(t)
    expected = np.zeros((15, 2))
    expected[5, 1] = 50e-6  # 1.0 ms is sample 5
    np.testing.assert_array_equal(offset, expected)
    hold = changes.hold_mask(t)
    np.testing.assert_array_equal(np.flatnonzero(hold), [10, 11, 12])


def test_glitch_outside_the_run_does_nothing():
    changes = PlantChanges(encoder_glitch=(EncoderGlitch("spike", 5.0),))
    assert not changes.position_offset_m(times(0.01)).any()


def test_velocity_noise_is_seeded_and_windowed():
    noise = VelocityNoise((0.01, 0.002), seed=7, start_s=0.5, end_s=1.0)
    t = times(2.0)
    a = PlantChanges(velocity_noise=noise).velocity_noise_m_s(t)
    b = PlantChanges(velocity_noise=noise).velocity_noise_m_s(t)
    np.testing.assert_array_equal(a, b)
    inside = (t >= 0.5) & (t < 1.0)
    assert not a[~inside].any()
    np.testing.assert_allclose(a[inside].std(axis=0), [0.01, 0.002], rtol=0.05)
    draws = np.random.default_rng(7).standard_normal((t.size, 2))
    np.testing.assert_array_equal(a[inside], draws[inside] * [0.01, 0.002])


def test_cogging_force_by_hand():
    changes = PlantChanges(cogging=(CoggingRipple("x", 0.05, 0.016), CoggingRipple("y", 0.02, 0.032, 0.5)))
    q = np.array([0.004, 0.010])
    expected = [0.05 * np.sin(2 * np.pi * 0.004 / 0.016), 0.02 * np.sin(2 * np.pi * 0.010 / 0.032 + 0.5)]
    np.testing.assert_allclose(changes.cogging_force_v(q), expected, rtol=1e-12)
    np.testing.assert_allclose(changes.cogging_force_v(np.array([0.004, 0.0])), [0.05, 0.02 * np.sin(0.5)])


@pytest.mark.parametrize(
    ("build", "field"),
    [
        (lambda: FrictionDrift("z", 0.0, 1.0, viscous_to_v_s_m=1.0), "friction_drift.axis"),
        (lambda: FrictionDrift("y", 5.0, 5.0, viscous_to_v_s_m=1.0), "friction_drift.end_s"),
        (lambda: FrictionDrift("y", 0.0, 1.0, viscous_to_v_s_m=-0.1), "friction_drift.viscous_to_v_s_m"),
        (lambda: FrictionDrift("y", 0.0, 1.0), "friction_drift.viscous_to_v_s_m"),
        (lambda: FrictionDrift("y", 0.0, 1.0, coulomb_to_v=float("nan")), "friction_drift.coulomb_to_v"),
        (lambda: PayloadChange(1.0, 25.0), "payload_change.mass_kg"),
        (lambda: PayloadChange(-1.0, 2.0), "payload_change.time_s"),
        (lambda: CoggingRipple("x", 0.05, 1e-4), "cogging.pitch_m"),
        (lambda: CoggingRipple("x", 3.0, 0.016), "cogging.amplitude_v"),
        (lambda: EncoderGlitch("spike", 1.0, offset_m=0.0), "encoder_glitch.offset_m"),
        (lambda: EncoderGlitch("drop", 1.0), "encoder_glitch.kind"),
        (lambda: EncoderGlitch("hold", 1.0, samples=0), "encoder_glitch.samples"),
        (lambda: VelocityNoise((0.01, 2.0)), "velocity_noise.std_m_s.y"),
        (lambda: VelocityNoise((0.01, 0.01), seed=-1), "velocity_noise.seed"),
        (
            lambda: PlantChanges(cogging=(CoggingRipple("x", 0.05, 0.016), CoggingRipple("x", 0.01, 0.016))),
            "cogging.axis",
        ),
        (
            lambda: PlantChanges(
                friction_drift=(
                    FrictionDrift("y", 0.0, 1.0, viscous_to_v_s_m=1.0),
                    FrictionDrift("y", 2.0, 3.0, viscous_to_v_s_m=1.2),
                )
            ),
            "friction_drift[1].axis",
        ),
    ],
)
def test_validation_names_the_field_and_range(build, field):
    with pytest.raises(ValueError) as info:
        build()
    message = str(info.value)
    assert message.startswith(field + ":"), message
    assert "\n" not in message
