"""MuJoCo's dry friction behaves like Coulomb friction.

MuJoCo's friction is a soft constraint; with its default softness a held axis
creeps (~0.4 mm/s at half the friction level) and the force reaches the
Coulomb level only near 9 mm/s. models/gantry.xml pins it stiff. These tests
check the result against the paper's model M q'' + B q' + Af sign(q') = u:
- stick: 90 % of Af from rest moves an axis less than 1 um in 1 s;
- break-away: 110 % of Af follows the analytic motion of the net force 0.1 Af;
- slip: sliding at 1 mm/s (and 0.3 mm/s) the friction force is at least 90 % of Af.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from gantry_twin import Payload, Plant

from .helpers import GEAR_N_PER_V, spec_theta

# The reference values (volt units), index 0 = X, 1 = Y.
SPEC_M = {kg: spec_theta(kg)[0:2] for kg in (0.0, 5.0)}
SPEC_B = spec_theta()[2:4]
SPEC_AF = spec_theta()[4:6]

CASES = [(payload, axis, sign) for payload in (0.0, 5.0) for axis in (0, 1) for sign in (1.0, -1.0)]


def push_from_rest(plant: Plant, axis: int, volts: float, duration_s: float) -> np.ndarray:
    """Constant input on one motor from rest at the centre; positions (N+1,) of that axis, metres."""
    plant.reset(np.zeros(2), np.zeros(2))
    plant.data.ctrl[plant.motor_index[axis]] = volts
    steps = round(duration_s / plant.timestep_s)
    q = np.empty(steps + 1)
    q[0] = plant.q_m[axis]
    for k in range(steps):
        mujoco.mj_step(plant.model, plant.data)
        q[k + 1] = plant.q_m[axis]
    return q


@pytest.mark.parametrize(("payload_kg", "axis", "sign"), CASES)
def test_ninety_percent_of_coulomb_level_sticks(payload_kg: float, axis: int, sign: float) -> None:
    plant = Plant(Payload(payload_kg))
    q = push_from_rest(plant, axis, sign * 0.9 * SPEC_AF[axis], 1.0)
    assert np.abs(q).max() < 1e-6


def breakaway_position_m(mass: float, damping: float, net_v: float, t_s: float) -> float:
    """Position from rest under a constant net force (volt units): M x'' + B x' = net."""
    tau = mass / damping
    return net_v / damping * (t_s - tau * (1.0 - math.exp(-t_s / tau)))


@pytest.mark.parametrize(("payload_kg", "axis", "sign"), CASES)
def test_hundred_ten_percent_breaks_away_as_the_coulomb_model_predicts(
    payload_kg: float, axis: int, sign: float
) -> None:
    plant = Plant(Payload(payload_kg))
    q = push_from_rest(plant, axis, sign * 1.1 * SPEC_AF[axis], 1.0)
    mass, damping, net = SPEC_M[payload_kg][axis], SPEC_B[axis], 0.1 * SPEC_AF[axis]
    expected = breakaway_position_m(mass, damping, net, 1.0)
    assert expected > 5e-3  # the model's prediction is a clear motion (several mm)
    assert sign * q[-1] > 100e-6
    assert sign * q[-1] == pytest.approx(expected, rel=0.02)
    # Early on, damping is negligible: x = (0.1 Af / M) t^2 / 2.
    t_early = 0.01
    k = round(t_early / plant.timestep_s)
    assert sign * q[k] == pytest.approx(0.5 * net / mass * t_early**2, rel=0.05)


def friction_row_force_n(plant: Plant, axis: int) -> float:
    """Force of the dry-friction constraint row of one joint (N, MuJoCo's sign)."""
    data = plant.data
    rows = np.flatnonzero(
        (data.efc_type == mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF) & (data.efc_id == plant.dof_index[axis])
    )
    assert rows.size == 1
    return float(data.efc_force[rows[0]])


@pytest.mark.parametrize("speed_m_s", [1e-3, 0.3e-3])
@pytest.mark.parametrize(("payload_kg", "axis", "sign"), CASES)
def test_slow_sliding_meets_full_coulomb_force(payload_kg: float, axis: int, sign: float, speed_m_s: float) -> None:
    """A stiff PI velocity loop holds 1 mm/s (acceptance) or 0.3 mm/s; friction is measured two ways.

    At 0.3 mm/s MuJoCo's default friction softness gives only ~35 % of Af on X
    (at 1 mm/s it is already saturated on these masses), so the slower case is
    the one that tells the stiff settings from the default.

    1. The constraint force MuJoCo applies on the friction row (efc_force).
    2. From the motion: at constant velocity the input balances damping and
       friction, so Af_measured = u - B v (volt units, the reference B).
    """
    plant = Plant(Payload(payload_kg))
    ts = plant.timestep_s
    v_ref = sign * speed_m_s
    mass = SPEC_M[payload_kg][axis]
    kp = mass * 200.0  # V/(m/s): 200 rad/s velocity bandwidth
    ki = kp * 50.0
    plant.reset(np.zeros(2), np.zeros(2))
    integral = 0.0
    steps = round(1.0 / ts)
    tail = round(0.2 / ts)
    v_tail, u_tail, f_tail = [], [], []
    for k in range(steps):
        error = v_ref - plant.dq_m_s[axis]
        integral += error * ts
        u = kp * error + ki * integral
        plant.data.ctrl[plant.motor_index[axis]] = u
        mujoco.mj_step(plant.model, plant.data)
        if k >= steps - tail:
            v_tail.append(plant.dq_m_s[axis])
            u_tail.append(u)
            f_tail.append(friction_row_force_n(plant, axis))
    v_mean = float(np.mean(v_tail))
    assert v_mean == pytest.approx(v_ref, rel=0.01)
    assert np.ptp(v_tail) < 0.02e-3  # steady sliding, not stick-slip
    # 1. MuJoCo's constraint force opposes the motion.
    friction_v = -sign * np.asarray(f_tail) / GEAR_N_PER_V
    assert friction_v.min() >= 0.9 * SPEC_AF[axis]
    assert friction_v.max() <= SPEC_AF[axis] * (1.0 + 1e-9)
    # 2. The force balance of the motion.
    from_motion = sign * (float(np.mean(u_tail)) - SPEC_B[axis] * v_mean)
    assert from_motion >= 0.9 * SPEC_AF[axis]
    assert from_motion == pytest.approx(SPEC_AF[axis], rel=0.02)
