"""LuGre friction in the plant (docs/friction.md): the friction alone against the LuGre equations, computed here.

- steady sliding at 16 speeds per direction and axis: the force within 2 % of
  Fc + (Fs - Fc) exp(-(v/vs)^2) + sigma2 v;
- a slow force ramp below Fs: pre-sliding displacement within 10 % of F / sigma0
  (small forces) and on the LuGre quasi-static curve, and a hysteresis loop on reversal;
- no divergence (MuJoCo's warnings, not only finiteness) for z started anywhere
  in [-2, 2] Fs / sigma0 at speeds up to 0.6 m/s;
- the bristle state at the start, the model edits, the true parameters by the
  paper's identification, friction drift on a LuGre axis.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from gantry_twin import Payload, Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import create
from gantry_twin.plant.faults import CoggingRipple, FrictionDrift, PlantChanges
from gantry_twin.plant.friction import Friction, FrictionError, LuGreAxis
from gantry_twin.run import execute
from gantry_twin.scenario import ScenarioError, build, load_scenario
from gantry_twin.scenario.files import shipped, shipped_scenarios

from .helpers import DAMPING_N_S_PER_M, FRICTION_N, GEAR_N_PER_V

# The LuGre parameters of these tests (SI), different per axis and from the defaults.
PARAMS = {
    "x": {"sigma0_n_m": 8.0e5, "sigma1_ns_m": 250.0, "fc_n": 6.9, "fs_n": 9.0, "vs_m_s": 0.004, "sigma2_ns_m": 34.5},
    "y": {"sigma0_n_m": 1.5e6, "sigma1_ns_m": 400.0, "fc_n": 10.35, "fs_n": 15.0, "vs_m_s": 0.008, "sigma2_ns_m": 48.3},
}
AXES = ("x", "y")


def lugre_plant(payload_kg: float = 0.0, **integration: object) -> Plant:
    friction = Friction(model="lugre", x=LuGreAxis(**PARAMS["x"]), y=LuGreAxis(**PARAMS["y"]), **integration)
    return Plant(Payload(payload_kg), friction=friction)


def expected_steady_n(axis: str, v: float) -> float:
    """The LuGre steady-sliding friction, written out here: sign(v) (Fc + (Fs - Fc) exp(-(v/vs)^2)) + sigma2 v."""
    p = PARAMS[axis]
    level = p["fc_n"] + (p["fs_n"] - p["fc_n"]) * math.exp(-((v / p["vs_m_s"]) ** 2))
    return math.copysign(level, v) + p["sigma2_ns_m"] * v


def friction_force_n(plant: Plant, axis: int) -> float:
    """The force the friction puts on a joint, as a resistance (positive opposes positive motion), N."""
    dof = plant.dof_index[axis]
    viscous = plant.model.dof_damping[dof] * plant.data.qvel[dof]
    return -float(plant.data.actuator_force[plant.friction_index[axis]]) + float(viscous)


def step_sample(plant: Plant) -> None:
    mujoco.mj_step(plant.model, plant.data, nstep=plant.substeps)


SPEEDS_M_S = np.geomspace(2.0e-4, 0.6, 16)


@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_steady_sliding_force_follows_the_lugre_curve(axis: int, direction: float) -> None:
    plant = lugre_plant()
    dof = plant.dof_index[axis]
    for speed in SPEEDS_M_S:
        v = direction * speed
        plant.reset(np.zeros(2), np.zeros(2))  # bristles at rest: the steady state is reached, not given
        settle_s = 0.05 + 20.0 * PARAMS[AXES[axis]]["fs_n"] / PARAMS[AXES[axis]]["sigma0_n_m"] / speed
        samples = int(min(settle_s, 0.4) / plant.timestep_s)
        for _ in range(samples):
            plant.data.qvel[dof] = v  # the carriage held at constant speed (prescribed motion)
            plant.data.qpos[plant.qpos_index] = 0.0  # stay mid-travel; friction sees only the velocity
            step_sample(plant)
        plant.data.qvel[dof] = v
        mujoco.mj_forward(plant.model, plant.data)
        got, want = friction_force_n(plant, axis), expected_steady_n(AXES[axis], v)
        assert got == pytest.approx(want, rel=0.02), f"v = {v:.4g} m/s"
        assert not plant.data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number


def ramp(plant: Plant, axis: int, forces_n: np.ndarray) -> np.ndarray:
    """Position of one axis (m) as its motor's force follows ``forces_n``, one value per sample, from rest."""
    plant.reset(np.zeros(2), np.zeros(2))
    x = np.empty(forces_n.size)
    for k, force in enumerate(forces_n):
        plant.data.ctrl[plant.motor_index[axis]] = force / GEAR_N_PER_V
        step_sample(plant)
        x[k] = plant.q_m[axis]
    return x


@pytest.mark.parametrize("axis", [0, 1])
def test_slow_force_ramp_below_fs_gives_presliding_and_hysteresis(axis: int) -> None:
    plant = lugre_plant()
    p = PARAMS[AXES[axis]]
    top = 0.5 * p["fc_n"]
    n = int(1.0 / plant.timestep_s)  # 1 s up, 1 s down: slow against the carriage's dynamics
    up = np.linspace(0.0, top, n)
    forces = np.concatenate([up, up[::-1]])
    x = ramp(plant, axis, forces)
    x_up, x_down = x[:n], x[n:][::-1]
    # Small forces: the bristle acts as the spring sigma0 (acceptance: within 10 % of F / sigma0).
    small = (up > 0.02 * p["fs_n"]) & (up <= 0.1 * p["fs_n"])
    np.testing.assert_allclose(x_up[small], up[small] / p["sigma0_n_m"], rtol=0.10)
    # The whole ramp: LuGre's quasi-static deflection from rest, dz/dx = 1 - sigma0 z / g with g = Fs at
    # creeping speed, x = -(Fs / sigma0) ln(1 - F / Fs); far from F / sigma0 near Fs.
    quasi_static = -(p["fs_n"] / p["sigma0_n_m"]) * np.log(1.0 - up / p["fs_n"])
    # (after 0.2 s: the lightly damped carriage-on-bristle mode excited by the ramp's start has decayed)
    np.testing.assert_allclose(x_up[up > 0.2 * top], quasi_static[up > 0.2 * top], rtol=0.03)
    assert np.abs(x).max() < 3.0 * top / p["sigma0_n_m"]  # it never slid
    # Hysteresis: back at zero force the carriage keeps part of its deflection, and the way down lies
    # above the way up (a loop, not a spring).
    assert x_down[0] > 0.05 * top / p["sigma0_n_m"]
    middle = (up > 0.2 * top) & (up < 0.8 * top)
    assert np.all(x_down[middle] > x_up[middle])


def coast(plant: Plant, axis: int, z0_m: float, v_m_s: float, samples: int = 100) -> tuple[bool, float]:
    """From bristle state z0 and speed v, no input: (MuJoCo warned, largest speed gain in m/s beyond what the
    bristle's stored energy sigma0 z0^2 / 2 can give the axis' mass)."""
    velocity = np.zeros(2)
    velocity[axis] = v_m_s
    plant.reset(np.zeros(2), velocity)
    actuator = plant.friction_index[axis]
    plant.data.act[plant.model.actuator_actadr[actuator]] = z0_m
    mujoco.mj_forward(plant.model, plant.data)
    mass = plant.model.body_subtreemass[plant.model.jnt_bodyid[plant.model.joint(AXES[axis]).id]]
    sigma0 = plant.model.actuator_dynprm[actuator, 5]
    allowed = abs(v_m_s) + math.sqrt(sigma0 * z0_m**2 / mass)
    gain = 0.0
    for _ in range(samples):
        step_sample(plant)
        speed = float(np.abs(plant.data.qvel[plant.dof_index[axis]]))
        gain = max(gain, speed - allowed) if math.isfinite(speed) else math.inf
    warned = any(w.number for w in plant.data.warning) or not np.isfinite(plant.data.act).all()
    return warned, gain


@pytest.mark.parametrize("axis", [0, 1])
def test_no_divergence_from_any_bristle_state_at_any_speed(axis: int) -> None:
    plant = lugre_plant(payload_kg=5.0)
    p = PARAMS[AXES[axis]]
    adr = plant.model.actuator_actadr[plant.friction_index[axis]]
    for z0 in np.linspace(-2.0, 2.0, 9) * p["fs_n"] / p["sigma0_n_m"]:
        for v in (-0.6, -0.3, -0.05, -1e-3, 0.0, 1e-3, 0.05, 0.3, 0.6):
            warned, gain = coast(plant, axis, z0, v)
            assert not warned, (z0, v)
            assert gain < 1e-4, (z0, v)  # friction and the bristle do not add energy
            assert abs(plant.data.act[adr]) <= max(abs(z0), p["fs_n"] / p["sigma0_n_m"]) * (1 + 1e-9)


def test_explicit_rk4_at_one_step_per_sample_is_caught() -> None:
    """The check above can fail: at the 0.2 ms sample the bristle is beyond explicit RK4's stability limit,
    and RK4's stages throw the carriage forward (or diverge)."""
    plant = lugre_plant(integrator="rk4", substeps=1)
    warned, gain = coast(plant, 0, 0.0, 0.3)
    assert warned or gain > 1e-3


def test_bristles_start_in_steady_sliding_on_path_and_undeflected_at_rest() -> None:
    plant = lugre_plant()
    v = np.array([0.3, -0.02])
    plant.reset(np.zeros(2), v)
    for axis, name in enumerate(AXES):
        z = plant.data.act[plant.model.actuator_actadr[plant.friction_index[axis]]]
        assert z * PARAMS[name]["sigma0_n_m"] == pytest.approx(
            expected_steady_n(name, v[axis]) - PARAMS[name]["sigma2_ns_m"] * v[axis]
        )
        assert friction_force_n(plant, axis) == pytest.approx(expected_steady_n(name, v[axis]), rel=1e-9)
    plant.reset(np.zeros(2), np.zeros(2))
    assert np.all(plant.data.act == 0.0)


def test_lugre_model_edits_keep_the_motors_and_take_friction_off_the_joints() -> None:
    coulomb, lugre = Plant(), lugre_plant()
    m = lugre.model
    np.testing.assert_array_equal(lugre.motor_index, coulomb.motor_index)
    np.testing.assert_array_equal(lugre.disturbance_index, coulomb.disturbance_index)
    assert m.nu == coulomb.model.nu  # the friction actuators take no ctrl slot
    np.testing.assert_array_equal(m.dof_frictionloss, 0.0)
    np.testing.assert_array_equal(coulomb.friction_index, [-1, -1])
    for axis, name in enumerate(AXES):
        a = lugre.friction_index[axis]
        assert m.actuator_gear[a, 0] == 1.0
        assert m.actuator_trnid[a, 0] == m.joint(name).id
        np.testing.assert_array_equal(
            m.actuator_dynprm[a, 5:7], [PARAMS[name]["sigma0_n_m"], PARAMS[name]["sigma1_ns_m"]]
        )
        np.testing.assert_array_equal(
            m.actuator_biasprm[a, 3:6], [PARAMS[name]["fc_n"], PARAMS[name]["fs_n"], PARAMS[name]["vs_m_s"]]
        )
    assert lugre.timestep_s == coulomb.timestep_s == 2e-4
    assert m.opt.timestep * lugre.substeps == pytest.approx(2e-4, rel=1e-15)


def test_default_lugre_takes_fc_and_sigma2_from_the_model() -> None:
    plant = Plant(friction=Friction(model="lugre"))
    for axis in range(2):
        a = plant.friction_index[axis]
        assert plant.model.actuator_biasprm[a, 3] == FRICTION_N[axis]
        assert plant.model.actuator_biasprm[a, 4] == pytest.approx(1.3 * FRICTION_N[axis])
        assert plant.model.dof_damping[plant.dof_index[axis]] == DAMPING_N_S_PER_M[axis]


def test_true_b_and_af_are_the_paper_identification_of_the_steady_curve() -> None:
    """An independent fit: the steady force along a sinusoidal 0.4 m/s motion in time, least squares on
    [sign v, v] (the paper's off-line identification), against Plant.true_parameters."""
    plant = lugre_plant()
    theta = plant.true_parameters()
    t = np.linspace(0.0, 2.0 * math.pi, 100001)[:-1]
    v = 0.4 * np.cos(t)
    for axis, name in enumerate(AXES):
        force = np.array([expected_steady_n(name, x) for x in v])
        (af, b), *_ = np.linalg.lstsq(np.column_stack([np.sign(v), v]), force, rcond=None)
        assert theta[4 + axis] == pytest.approx(af / GEAR_N_PER_V, rel=1e-3)
        assert theta[2 + axis] == pytest.approx(b / GEAR_N_PER_V, rel=1e-3)
        assert af > PARAMS[name]["fc_n"]  # the Stribeck bump raises the identified Coulomb level


def test_friction_drift_on_a_lugre_axis_moves_fc_fs_and_sigma2_and_the_true_theta() -> None:
    plant = lugre_plant()
    before = plant.model.actuator_biasprm.copy(), plant.model.dof_damping.copy()
    drift = FrictionDrift(axis="y", start_s=0.1, end_s=0.2, viscous_to_v_s_m=0.9, coulomb_to_v=0.2)
    trace = simulate(
        plant, circle(), TimingLaw(2.0), create("diarc"), 0.3, changes=PlantChanges(friction_drift=(drift,))
    )
    # Restored after the run.
    np.testing.assert_array_equal(plant.model.actuator_biasprm, before[0])
    np.testing.assert_array_equal(plant.model.dof_damping, before[1])
    # At the end the true theta is that of a plant built with the drifted values.
    p = dict(PARAMS["y"], fc_n=0.2 * GEAR_N_PER_V, sigma2_ns_m=0.9 * GEAR_N_PER_V)
    p["fs_n"] = p["fc_n"] * PARAMS["y"]["fs_n"] / PARAMS["y"]["fc_n"]
    drifted = Plant(friction=Friction(model="lugre", x=LuGreAxis(**PARAMS["x"]), y=LuGreAxis(**p)))
    np.testing.assert_allclose(trace.true_theta_t[-1], drifted.true_parameters(), rtol=1e-12)
    np.testing.assert_allclose(trace.true_theta_t[0], plant.true_parameters(), rtol=1e-12)


def test_physical_ranges_are_checked_with_the_field_named() -> None:
    with pytest.raises(ValueError, match=r"lugre.sigma0_n_m: the pre-sliding distance"):
        LuGreAxis(sigma0_n_m=1e9, fc_n=6.9)
    with pytest.raises(ValueError, match=r"lugre.fs_n: the ratio Fs / Fc must be in \[1, 2\]"):
        LuGreAxis(fc_n=6.9, fs_n=20.0)
    with pytest.raises(ValueError, match=r"lugre.vs_m_s: must be in"):
        LuGreAxis(vs_m_s=1.0)
    with pytest.raises(FrictionError, match=r"friction.y.sigma0_n_m"):  # Fc from the model (10.35 N)
        Plant(friction=Friction(model="lugre", y=LuGreAxis(sigma0_n_m=1e9)))
    with pytest.raises(FrictionError, match=r"friction.x.sigma1_ns_m: must be at most the critical damping"):
        Plant(friction=Friction(model="lugre", x=LuGreAxis(sigma1_ns_m=1e5)))


REFERENCE_INTEGRATION = ("plant.friction.integrator=rk4", "plant.friction.substeps=100")  # 2 us physics


def lugre_scenario_eps_c(path: object, extra: tuple[str, ...] = ()) -> np.ndarray:
    """eps_c (m) of a shipped scenario run for 1 s with LuGre friction (monitor off: its windows need 10 s)."""
    overrides = [
        "plant.friction.model=lugre",
        "duration_s=1.0",
        "window_s=[0.0, 1.0]",
        "estimates_window_s=[0.0, 1.0]",
        "monitor.enable=false",
        *extra,
    ]
    built = build(load_scenario(path, overrides))
    trace = execute(built)
    assert not any(w.number for w in built.plant.data.warning)
    return np.asarray(trace.eps_c_m)


#: The scenarios the suite checks (the plain circle, and the drift that moves the LuGre parameters during the
#: run); the other seven with ``-m exhaustive`` (the same check, about 10 s each), to keep the suite's time.
LUGRE_IN_SUITE = ("no_load_circle", "friction_drift_circle")


@pytest.mark.slow
@pytest.mark.parametrize(
    "path",
    [pytest.param(p, marks=() if p.stem in LUGRE_IN_SUITE else pytest.mark.exhaustive) for p in shipped_scenarios()],
    ids=lambda p: p.stem,
)
def test_shipped_scenarios_with_lugre_agree_with_a_2_us_physics_reference(path: object) -> None:
    """The chosen integration (LUGRE_INTEGRATOR, LUGRE_SUBSTEPS) within 0.2 um of eps_c with 2 us RK4 physics
    under the same 0.2 ms control, the encoder's quantisation off: the integration error alone. With the 0.5 um
    counts a difference of a fraction of a count flips a reading and the controller amplifies it: those
    differences do not fall with the sub-step (docs/friction.md, "Integration")."""
    ideal = ("sensing.quantize=false",)
    chosen = lugre_scenario_eps_c(path, ideal)
    reference = lugre_scenario_eps_c(path, (*REFERENCE_INTEGRATION, *ideal))
    assert np.abs(chosen - reference).max() < 0.2e-6


def test_a_scenario_chooses_the_friction_and_its_errors_name_the_field() -> None:
    built = build(load_scenario(shipped("no_load_circle"), ["plant.model=paper", "plant.friction.model=lugre"]))
    assert built.plant.friction.lugre and built.plant.substeps > 1
    assert (built.plant.friction_index >= 0).all()
    coulomb = build(load_scenario(shipped("no_load_circle"), ["plant.model=paper"]))  # the ideal plant's own
    assert not coulomb.plant.friction.lugre and coulomb.plant.substeps == 1
    rig = build(load_scenario(shipped("no_load_circle")))  # the default machine's own: LuGre
    assert rig.plant.friction.lugre and rig.plant.substeps > 1
    with pytest.raises(ScenarioError) as too_stiff:
        build(
            load_scenario(shipped("no_load_circle"), ["plant.friction.model=lugre", "plant.friction.y.sigma0_n_m=1e9"])
        )
    assert too_stiff.value.field == "plant.friction.y.sigma0_n_m"
    assert "pre-sliding distance" in too_stiff.value.message
    with pytest.raises(ScenarioError) as too_fast:
        load_scenario(shipped("no_load_circle"), ["plant.friction.x.vs_m_s=1.0"])
    assert too_fast.value.field == "plant.friction.x.vs_m_s"


def test_both_backends_give_the_same_lugre_trace_with_drift_and_cogging() -> None:
    changes = PlantChanges(
        friction_drift=(FrictionDrift(axis="x", start_s=0.0, end_s=0.06, coulomb_to_v=0.15, viscous_to_v_s_m=0.6),),
        cogging=(CoggingRipple(axis="y", amplitude_v=0.05, pitch_m=0.016),),
    )
    traces = [
        simulate(lugre_plant(), circle(), TimingLaw(2.0), create("diarc"), 0.06, backend=b, changes=changes)
        for b in ("compiled", "reference")
    ]
    np.testing.assert_array_equal(traces[0].q_m, traces[1].q_m)
    np.testing.assert_array_equal(traces[0].u_v, traces[1].u_v)
