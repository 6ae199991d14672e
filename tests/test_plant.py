"""The compiled MJCF gantry against the reference machine (docs/equations.md, the plant; tests/helpers.py).

Moving masses are checked two ways: MuJoCo's joint-space inertia (``mj_fullM``,
what :func:`true_parameters` uses) against the body masses summed over each
joint's subtree of the kinematic tree (``body_mass`` / ``body_parentid``).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from gantry_twin import Payload, Plant
from gantry_twin.plant.model import PAYLOAD_MAX_KG, PAYLOAD_OFFSET_MAX_M, THETA_NAMES, moving_masses_kg

from .helpers import DAMPING_N_S_PER_M, FRICTION_N, GEAR_N_PER_V, MASS_NO_LOAD_KG

# The expected theta (volt units; docs/equations.md, the plant) for no load and the 5 kg payload of Set 2.
THETA_NO_LOAD = np.array([0.12, 0.50, 0.5, 0.7, 0.10, 0.15, 0.0, 0.0])
THETA_5KG = np.array([0.1925, 0.5725, 0.5, 0.7, 0.10, 0.15, 0.0, 0.0])


def subtree_mass_kg(model: mujoco.MjModel, body_id: int) -> float:
    """Mass of a body and every body below it, from the parent links alone (kg)."""
    total = 0.0
    for b in range(model.nbody):
        a = b
        while a != 0 and a != body_id:
            a = int(model.body_parentid[a])
        if a == body_id:
            total += float(model.body_mass[b])
    return total


def chain_masses_kg(plant: Plant) -> np.ndarray:
    """Moving mass of each slide joint (X, Y): the subtree mass of the joint's body."""
    m = plant.model
    return np.array([subtree_mass_kg(m, int(m.jnt_bodyid[m.joint(a).id])) for a in ("x", "y")])


def full_mass_matrix(plant: Plant) -> np.ndarray:
    data = mujoco.MjData(plant.model)
    mujoco.mj_forward(plant.model, data)
    full = np.zeros((plant.model.nv, plant.model.nv))
    mujoco.mj_fullM(plant.model, data, full)
    return full


@pytest.mark.parametrize(
    ("payload_kg", "expected_kg"),
    [(0.0, MASS_NO_LOAD_KG), (5.0, MASS_NO_LOAD_KG + 5.0), (2.5, MASS_NO_LOAD_KG + 2.5)],
)
def test_moving_masses_match_kinematic_chain(payload_kg: float, expected_kg: np.ndarray) -> None:
    plant = Plant(Payload(payload_kg))
    chain = chain_masses_kg(plant)
    np.testing.assert_allclose(chain, expected_kg, rtol=1e-12)
    np.testing.assert_allclose(moving_masses_kg(plant.model, plant.dof_index), chain, rtol=1e-12)
    # The axes are orthogonal slides: no inertial coupling between them.
    full = full_mass_matrix(plant)
    assert abs(full[0, 1]) < 1e-12 and abs(full[1, 0]) < 1e-12


def test_payload_offset_does_not_change_slide_masses() -> None:
    centred = Plant(Payload(5.0)).true_parameters()
    offset = Plant(Payload(5.0, (0.1, -0.1, 0.2))).true_parameters()
    np.testing.assert_allclose(offset, centred, rtol=1e-12)


def test_damping_friction_gear_and_ctrl_range() -> None:
    plant = Plant()
    m = plant.model
    np.testing.assert_allclose(m.dof_damping[plant.dof_index], DAMPING_N_S_PER_M, rtol=1e-12)
    np.testing.assert_allclose(m.dof_frictionloss[plant.dof_index], FRICTION_N, rtol=1e-12)
    np.testing.assert_allclose(plant.gear_n_per_v, [GEAR_N_PER_V, GEAR_N_PER_V])
    np.testing.assert_allclose(plant.ctrl_range_v, [[-10.0, 10.0], [-10.0, 10.0]])
    assert m.actuator_ctrllimited[plant.motor_index].all()
    # The disturbance motors have the same gain and act on the same joints.
    np.testing.assert_allclose(m.actuator_gear[plant.disturbance_index, 0], [GEAR_N_PER_V, GEAR_N_PER_V])
    for motor, disturbance in zip(plant.motor_index, plant.disturbance_index, strict=True):
        assert m.actuator_trnid[motor, 0] == m.actuator_trnid[disturbance, 0]
    # Travel 510 mm: the joint ranges hold the paper's 0.2 m circle and ellipse with margin.
    for name in ("x", "y"):
        lo, hi = m.joint(name).range
        assert lo <= -0.25 and hi >= 0.25 and hi - lo <= 0.510 + 1e-12


@pytest.mark.parametrize(("payload_kg", "theta"), [(0.0, THETA_NO_LOAD), (5.0, THETA_5KG)])
def test_true_parameters_are_the_spec_theta(payload_kg: float, theta: np.ndarray) -> None:
    plant = Plant(Payload(payload_kg))
    got = plant.true_parameters()
    assert got.shape == (len(THETA_NAMES),)
    # The expected theta rounds 13.28 / 69 and 39.5 / 69 to four digits.
    np.testing.assert_allclose(got, theta, atol=5e-5)
    # And exactly the SI quantities divided by the gear.
    si = np.concatenate([chain_masses_kg(plant), DAMPING_N_S_PER_M, FRICTION_N]) / GEAR_N_PER_V
    np.testing.assert_allclose(got[:6], si, rtol=1e-12)


def test_any_payload_mass_gives_its_theta() -> None:
    got = Plant(Payload(2.5)).true_parameters()
    np.testing.assert_allclose(got[:2], (MASS_NO_LOAD_KG + 2.5) / GEAR_N_PER_V, rtol=1e-12)


def test_api_orders_x_first_although_mujoco_orders_y_first() -> None:
    plant = Plant()
    m = plant.model
    # MuJoCo numbers the DOFs parent first: Y (the lower carriage) is DOF 0.
    assert m.joint("y").dofadr[0] < m.joint("x").dofadr[0]
    # The API's index 0 is the X joint, whose axis is world x.
    np.testing.assert_allclose(m.jnt_axis[m.joint("x").id], [1, 0, 0])
    assert plant.dof_index[0] == m.joint("x").dofadr[0]
    assert plant.qpos_index[0] == m.joint("x").qposadr[0]
    assert m.actuator_trnid[plant.motor_index[0], 0] == m.joint("x").id
    # Behaviour: the tool site sits at (q_x, q_y) in the world after a reset.
    plant.reset(np.array([0.1, -0.05]), np.zeros(2))
    np.testing.assert_allclose(plant.data.site("tool").xpos[:2], [0.1, -0.05], atol=1e-12)
    np.testing.assert_allclose(plant.q_m, [0.1, -0.05])
    # Behaviour: a push on the API's X motor moves the tool along world x only.
    plant.data.ctrl[plant.motor_index[0]] = 1.0
    for _ in range(500):
        mujoco.mj_step(plant.model, plant.data)
    mujoco.mj_forward(plant.model, plant.data)  # site positions of the final state
    moved = plant.data.site("tool").xpos[:2] - [0.1, -0.05]
    assert moved[0] > 1e-3
    assert abs(moved[1]) < 1e-12
    np.testing.assert_allclose(plant.q_m - [0.1, -0.05], moved, atol=1e-12)
    assert plant.dq_m_s[0] > 0.0 and plant.dq_m_s[1] == 0.0


# ---- payload validation --------------------------------------------------------------

MASS_RANGE_TEXT = f"[0, {PAYLOAD_MAX_KG}]"


@pytest.mark.parametrize(
    "mass",
    [-1.0, -1e-9, math.nan, math.inf, -math.inf, True, False, "5", None, PAYLOAD_MAX_KG + 0.1, 1e9],
)
def test_bad_payload_mass_names_field_and_range(mass: object) -> None:
    with pytest.raises(ValueError, match=r"payload\.mass_kg") as info:
        Payload(mass)  # type: ignore[arg-type]
    message = str(info.value)
    assert MASS_RANGE_TEXT in message
    assert "\n" not in message


@pytest.mark.parametrize("mass", [0, 0.0, 2.5, 5, PAYLOAD_MAX_KG, np.float64(3.0), np.int64(4)])
def test_good_payload_masses_compile(mass: float) -> None:
    plant = Plant(Payload(mass))
    np.testing.assert_allclose(plant.true_parameters()[0], (8.28 + float(mass)) / GEAR_N_PER_V, rtol=1e-12)


@pytest.mark.parametrize(
    ("offset", "field", "limit"),
    [
        ((0.2, 0.0, 0.05), "x", PAYLOAD_OFFSET_MAX_M[0]),
        ((0.0, -0.11, 0.05), "y", PAYLOAD_OFFSET_MAX_M[1]),
        ((0.0, 0.0, math.nan), "z", PAYLOAD_OFFSET_MAX_M[2]),
        ((0.0, math.inf, 0.0), "y", PAYLOAD_OFFSET_MAX_M[1]),
        (("0", 0.0, 0.0), "x", PAYLOAD_OFFSET_MAX_M[0]),
        ((0.0, True, 0.0), "y", PAYLOAD_OFFSET_MAX_M[1]),
    ],
)
def test_bad_payload_offset_component_names_field_and_range(offset: tuple, field: str, limit: float) -> None:
    with pytest.raises(ValueError, match=rf"payload\.offset_m\.{field}") as info:
        Payload(5.0, offset)
    assert f"[-{limit}, {limit}]" in str(info.value)


@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.0, 0.0, 0.0, 0.0), 0.05, "abc", None])
def test_bad_payload_offset_shape_names_field(offset: object) -> None:
    with pytest.raises(ValueError, match=r"payload\.offset_m") as info:
        Payload(5.0, offset)  # type: ignore[arg-type]
    assert "three" in str(info.value)
