"""The loop applies PlantChanges to MuJoCo as an independently built plant would behave."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from gantry_twin import Payload, Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import DIARC, PD
from gantry_twin.plant.faults import CoggingRipple, FrictionDrift, PayloadChange, PlantChanges
from gantry_twin.plant.model import moving_masses_kg

ZERO_PD = dict(kp_v_m=(0.0, 0.0), kd_v_s_m=(0.0, 0.0), kv_v_s_m=(0.0, 0.0), ka_v_s2_m=(0.0, 0.0))


def test_massless_payload_body_changes_the_joint_inertia_at_run_time():
    plant = Plant(payload_body=True)
    bare = moving_masses_kg(plant.model, plant.dof_index)
    np.testing.assert_array_equal(bare, moving_masses_kg(Plant().model, Plant().dof_index))
    plant.model.body_mass[plant.payload_body_id] = 5.0  # no recompile, no mj_setConst
    np.testing.assert_allclose(moving_masses_kg(plant.model, plant.dof_index), bare + 5.0, rtol=1e-14)
    assert Plant().payload_body_id is None


def test_payload_from_t0_behaves_like_a_compiled_5kg_payload():
    changes = PlantChanges(payload_change=(PayloadChange(0.0, 5.0),))
    a = simulate(Plant(payload_body=True), circle(), TimingLaw(2.0), DIARC(), 0.5, changes=changes)
    b = simulate(Plant(Payload(5.0)), circle(), TimingLaw(2.0), DIARC(), 0.5)
    assert np.abs(a.q_m - b.q_m).max() < 1e-9  # although a's dof_invweight0 is still the unloaded one
    np.testing.assert_allclose(a.true_theta_t[-1], b.true_theta, rtol=1e-12)


def test_payload_change_needs_a_payload_body():
    with pytest.raises(ValueError, match="payload_body=True"):
        simulate(
            Plant(),
            circle(),
            TimingLaw(2.0),
            DIARC(),
            0.01,
            changes=PlantChanges(payload_change=(PayloadChange(0.0, 5.0),)),
        )


def test_friction_drift_equals_an_edited_model_after_the_drift():
    """A drift completed at once (1 ms) leaves the plant as a model built with the new damping and friction."""
    changes = PlantChanges(
        friction_drift=(
            FrictionDrift(
                "y", 0.0, 1e-3, viscous_from_v_s_m=0.91, viscous_to_v_s_m=0.91, coulomb_from_v=0.2, coulomb_to_v=0.2
            ),
        )
    )
    a = simulate(Plant(), circle(), TimingLaw(2.0), DIARC(), 0.3, changes=changes)
    plant = Plant()
    plant.model.dof_damping[plant.dof_index[1]] = 0.91 * 69.0
    plant.model.dof_frictionloss[plant.dof_index[1]] = 0.2 * 69.0
    b = simulate(plant, circle(), TimingLaw(2.0), DIARC(), 0.3)
    np.testing.assert_array_equal(a.q_m, b.q_m)
    assert a.true_theta[3] == pytest.approx(0.91) and a.true_theta[5] == pytest.approx(0.2)


@pytest.mark.parametrize("backend", ["compiled", "reference"])
def test_cogging_is_a_position_periodic_input_force(backend):
    """Zero-gain PD: the plant driven by cogging alone, against a plain mj_step loop fed the public
    PlantChanges.cogging_force_v (itself checked by hand in test_faults.py)."""
    changes = PlantChanges(cogging=(CoggingRipple("x", 0.5, 0.016), CoggingRipple("y", 0.3, 0.01, 1.0)))
    trace = simulate(Plant(), circle(), TimingLaw(2.0), PD(**ZERO_PD), 0.2, backend=backend, changes=changes)
    plant = Plant()
    plant.reset(trace.q_d_m[0], circle().derivatives(np.zeros(1))[1][0] * 2.0)
    q = np.empty_like(trace.q_m)
    for k in range(q.shape[0]):
        q[k] = plant.q_m
        plant.data.ctrl[plant.motor_index] = 0.0
        plant.data.ctrl[plant.disturbance_index] = changes.cogging_force_v(q[k])
        mujoco.mj_step(plant.model, plant.data)
    np.testing.assert_allclose(trace.q_m, q, rtol=0, atol=1e-15)
    free = simulate(Plant(), circle(), TimingLaw(2.0), PD(**ZERO_PD), 0.2, backend=backend)
    assert np.abs(free.q_m - trace.q_m).max() > 1e-6  # the ripple moved the plant
