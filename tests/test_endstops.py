"""The travel end stops of models/gantry.xml.

A carriage driven at the full DAC voltage from rest, near the end or from the
far end of its travel, with and without a 20 kg payload, must move as the
reference machine computes until it meets the end stop, never run more than 1 mm
past the travel end, and stay within 1 mm of it, at rest, while still pushed.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from gantry_twin import Payload, Plant
from gantry_twin.plant.model import AXES

from .helpers import DAC_LIMIT_V, TRAVEL_END_M, pushed_from_rest_m

#: How close to the travel end a stopped carriage must stay, m.
STOP_TOLERANCE_M = 1e-3
#: Where the carriage starts, measured from the end it is driven to, m: near (a slow arrival) and from the
#: other end of the travel (the fastest arrival the full voltage allows).
NEAR_M = 0.005
FAR_M = 2 * TRAVEL_END_M - 0.005
#: How long the carriage is pushed after it reaches the end, s.
HOLD_S = 0.2


def drive(axis: int, volts: float, payload_kg: float, start_m: float, duration_s: float):
    """Step the model from rest at ``start_m`` with ``volts`` on one motor: (t s, q m, q' m/s) after each step."""
    plant = Plant(Payload(payload_kg))
    q0 = np.zeros(2)
    q0[axis] = start_m
    plant.reset(q0, np.zeros(2))
    n = int(round(duration_s / plant.timestep_s))
    q, v = np.empty(n), np.empty(n)
    motor = plant.motor_index[axis]
    for k in range(n):
        plant.data.ctrl[motor] = volts
        mujoco.mj_step(plant.model, plant.data)
        q[k], v[k] = plant.q_m[axis], plant.dq_m_s[axis]
    return np.arange(1, n + 1) * plant.timestep_s, q, v


@pytest.mark.parametrize("payload_kg", [0.0, 20.0])  # no load and the largest payload accepted
@pytest.mark.parametrize("distance_m", [NEAR_M, FAR_M], ids=["near", "far"])
@pytest.mark.parametrize("direction", [1, -1], ids=["plus", "minus"])
@pytest.mark.parametrize("axis", [0, 1], ids=AXES)
def test_end_stop_holds_within_1mm_at_full_voltage(axis, direction, distance_m, payload_kg):
    end = direction * TRAVEL_END_M
    start = end - direction * distance_m
    volts = direction * DAC_LIMIT_V

    # The free motion of the reference machine: when it would reach the end.
    fine = np.arange(0.0, 2.0, 1e-6)
    arrival_s = fine[np.argmax(direction * (start + pushed_from_rest_m(fine, axis, volts, payload_kg) - end) >= 0)]
    t, q, v = drive(axis, volts, payload_kg, start, arrival_s + HOLD_S)
    free = start + pushed_from_rest_m(t, axis, volts, payload_kg)
    beyond = direction * (q - end)  # > 0: past the travel end

    # Until 1 mm before the end the carriage moves as computed: the full voltage drives it, nothing else acts.
    approach = direction * (end - free) > STOP_TOLERANCE_M
    assert approach.sum() > 10
    np.testing.assert_allclose(q[approach], free[approach], rtol=0, atol=1e-6)
    # It never runs more than 1 mm past the end ...
    assert beyond.max() <= STOP_TOLERANCE_M, f"ran {beyond.max() * 1e3:.3f} mm past the travel end"
    # ... and once within 1 mm of it, it stays there (no rebound), ending at rest while still pushed.
    reached = np.argmax(np.abs(beyond) <= STOP_TOLERANCE_M)
    assert np.abs(beyond[reached]) <= STOP_TOLERANCE_M
    assert np.abs(beyond[reached:]).max() <= STOP_TOLERANCE_M, "bounced back off the end stop"
    assert t[reached] <= arrival_s + 0.001  # it got there when the free motion said, not crawling in later
    assert abs(v[-1]) < 1e-5


def test_end_stop_holds_whatever_the_arrival_phase():
    """The fastest arrival (X, no load, from the far end) at start points spread over one sample's travel.

    Where in a 0.2 ms step the carriage meets the stop decides how deep it goes:
    the worst phase must hold too.
    """
    axis, end = 0, TRAVEL_END_M
    fine = np.arange(0.0, 1.0, 1e-6)
    free = pushed_from_rest_m(fine, axis, DAC_LIMIT_V)
    arrival_s = fine[np.argmax(free >= FAR_M)]
    step_travel_m = np.interp(arrival_s, fine, np.gradient(free, fine)) * 2e-4  # the speed there times one sample
    worst = []
    for shift in np.linspace(0.0, step_travel_m, 16, endpoint=False):
        _, q, _ = drive(axis, DAC_LIMIT_V, 0.0, end - FAR_M - shift, arrival_s + 0.05)
        beyond = q - end
        peak = int(np.argmax(beyond))
        worst.append((beyond[peak], -beyond[peak:].min()))
    overrun, rebound = np.max(worst, axis=0)
    assert overrun <= STOP_TOLERANCE_M, f"ran {overrun * 1e3:.3f} mm past the travel end"
    assert rebound <= STOP_TOLERANCE_M, f"bounced back to {rebound * 1e3:.3f} mm inside the travel end"
