"""System identification from the simulation itself.

Both axes are driven open loop through the control motors (volts) with a sum of
cosines; the carriage positions are recorded every step, and M, B, Af (volt
units) of the paper's model ``M q'' + B q' + Af sign(q') = u`` are fitted by
least squares. Velocity and acceleration come from central differences of the
sampled positions only, as they would on the rig (without the encoder), so the
fit never reads MuJoCo's damping or friction back: it checks that MuJoCo's
joint ``damping`` and ``frictionloss`` act as the paper's viscous and Coulomb
terms. The Coulomb regressor is sign(v), MuJoCo's true dry friction, not the
controller's atan model.

Cosines (not sines) are used because, for a first-order velocity response
1/(M s + B) starting from rest, a cosine input leaves no mean drift of the
position, so the axes stay well inside the +-255 mm travel.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from gantry_twin import Payload, Plant

from .helpers import spec_theta

# The reference values (volt units), index 0 = X, 1 = Y.
SPEC_M = {kg: spec_theta(kg)[0:2] for kg in (0.0, 5.0)}
SPEC_B = spec_theta()[2:4]
SPEC_AF = spec_theta()[4:6]
# (amplitude V, frequency Hz) per axis: low frequencies excite damping and friction,
# high ones the mass. Y is heavier and gets larger inputs.
EXCITATION = (
    ((0.3, 1.0), (0.6, 2.5), (1.0, 6.0)),
    ((1.0, 0.6), (1.5, 1.5), (2.0, 4.0)),
)
DURATION_S = 3.0


def excitation_volts(t_s: np.ndarray, axes: tuple[int, ...]) -> np.ndarray:
    u = np.zeros((t_s.size, 2))
    for axis in axes:
        for amplitude, freq in EXCITATION[axis]:
            u[:, axis] += amplitude * np.cos(2.0 * np.pi * freq * t_s)
    return u


def run_open_loop(plant: Plant, u_v: np.ndarray) -> np.ndarray:
    """Apply u_v[k] (volts, X/Y) during step k from rest at the centre; positions (N+1, 2), metres."""
    plant.reset(np.zeros(2), np.zeros(2))
    q = np.empty((u_v.shape[0] + 1, 2))
    q[0] = plant.q_m
    for k, u in enumerate(u_v):
        plant.data.ctrl[plant.motor_index] = u
        mujoco.mj_step(plant.model, plant.data)
        q[k + 1] = plant.q_m
    return q


def fit_axis(q_m: np.ndarray, u_v: np.ndarray, ts_s: float) -> np.ndarray:
    """Least-squares [M, B, Af] (volt units) of one axis from positions q[0..N] and inputs u[0..N-1].

    u[k] acts between samples k and k+1, so it pairs with the central second
    difference at sample k (k = 1..N-1).
    """
    v = (q_m[2:] - q_m[:-2]) / (2.0 * ts_s)
    a = (q_m[2:] - 2.0 * q_m[1:-1] + q_m[:-2]) / ts_s**2
    regressor = np.column_stack([a, v, np.sign(v)])
    theta, *_ = np.linalg.lstsq(regressor, u_v[1:], rcond=None)
    return theta


@pytest.mark.parametrize("payload_kg", [0.0, 5.0])
def test_open_loop_fit_recovers_spec_parameters(payload_kg: float) -> None:
    plant = Plant(Payload(payload_kg))
    ts = plant.timestep_s
    t = np.arange(round(DURATION_S / ts)) * ts
    u = excitation_volts(t, (0, 1))
    q = run_open_loop(plant, u)
    # The fit is only meaningful if no joint limit ever engaged, and the axes really moved.
    assert np.abs(q).max() < 0.25
    assert np.ptp(q, axis=0).min() > 0.05
    for axis in (0, 1):
        v = np.diff(q[:, axis]) / ts
        assert np.count_nonzero(np.diff(np.sign(v))) >= 6, "need several velocity reversals to see friction"
        mass, damping, friction = fit_axis(q[:, axis], u[:, axis], ts)
        assert mass == pytest.approx(SPEC_M[payload_kg][axis], rel=0.02)
        assert damping == pytest.approx(SPEC_B[axis], rel=0.02)
        assert friction == pytest.approx(SPEC_AF[axis], rel=0.05)


@pytest.mark.parametrize("axis", [0, 1])
def test_single_axis_fit_and_no_cross_coupling(axis: int) -> None:
    """Driving one axis alone identifies it just as well and never moves the other joint.

    The X carriage rides on Y: moving Y carries X along but does not move it
    relative to Y (the X joint stays at 0), and moving X exerts no force on Y.
    """
    plant = Plant()
    ts = plant.timestep_s
    t = np.arange(round(DURATION_S / ts)) * ts
    u = excitation_volts(t, (axis,))
    q = run_open_loop(plant, u)
    other = 1 - axis
    assert np.abs(q[:, other]).max() == 0.0
    mass, damping, friction = fit_axis(q[:, axis], u[:, axis], ts)
    assert mass == pytest.approx(SPEC_M[0.0][axis], rel=0.02)
    assert damping == pytest.approx(SPEC_B[axis], rel=0.02)
    assert friction == pytest.approx(SPEC_AF[axis], rel=0.05)
