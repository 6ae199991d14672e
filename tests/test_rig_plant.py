"""The rig plant's own properties (gantry_twin.plant.model, models/rig.xml; docs/rig-plant.md).

The static input offset dN(q) and the force ripple are input forces at the true position: checked
against an open-loop solution written out here and against a plain mj_step loop fed the formula
written out here. The rig's true parameters are checked against the paper's identification
computed here by least squares from the LuGre steady curve; the identification constraint against
the paper's numbers, by that steady-curve fit and by ``gantry-twin identify`` on an excitation log.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from gantry_twin import Plant, TimingLaw, circle, paper_ellipse, simulate
from gantry_twin.controllers import PD
from gantry_twin.plant.effects import (
    ForceRipple,
    InputOffset,
    OffsetAxis,
    RippleAxis,
    RippleHarmonic,
    file_properties,
)
from gantry_twin.plant.friction import lugre_parameters
from gantry_twin.plant.model import PlantSettings, default_model_path
from gantry_twin.scenario import ScenarioError, build, load_scenario, shipped

from .helpers import DAMPING_N_S_PER_M, FRICTION_N, GEAR_N_PER_V, MASS_NO_LOAD_KG, TRAVEL_END_M

ZERO_PD = dict(kp_v_m=(0.0, 0.0), kd_v_s_m=(0.0, 0.0), kv_v_s_m=(0.0, 0.0), ka_v_s2_m=(0.0, 0.0))
#: The paper's nominal M (V/(m/s^2)), Af (V) and B (V/(m/s)): what the paper's identification of the rig returned
#: (Table 3's theta_iN).
PAPER_M_V_S2_M = np.array([0.12, 0.5])
PAPER_AF_V = np.array([0.1, 0.15])
PAPER_B_V_S_M = np.array([0.5, 0.7])
#: The identification constraint's tolerance: both identifications of the rig within 3 % of the paper's B and Af
#: (M within 1 %), docs/rig-plant.md.
IDENTIFICATION_REL = 0.03
MASS_REL = 0.01


def offset_and_ripple_v(q_m: np.ndarray, offset: InputOffset, ripple: ForceRipple) -> np.ndarray:
    """dN(q) = c + h q / 0.255 m plus sum_k a_k sin(2 pi k q / pitch + phi_k), volts, written out again."""
    out = np.zeros(2)
    for i, name in enumerate(("x", "y")):
        o, r = getattr(offset, name), getattr(ripple, name)
        out[i] = o.constant_v + o.half_travel_v * q_m[i] / TRAVEL_END_M
        for k, h in enumerate(r.harmonics, start=1):
            out[i] += h.amplitude_v * math.sin(2.0 * math.pi * k * q_m[i] / r.pitch_m + h.phase_rad)
    return out


@pytest.mark.parametrize("backend", ["compiled", "reference"])
def test_a_constant_offset_is_the_force_dn_kf(backend):
    """X from rest under dN = 0.15 V alone (zero-gain PD, the paper's Coulomb friction): M v' = dN kf - Fc - B v,
    so v(t) = V (1 - exp(-t / tau)), x(t) = x0 + V (t - tau (1 - exp(-t / tau))), V = (dN kf - Fc) / B, tau = M / B.
    Y's 0.1 V (6.9 N) is below its 10.35 N Coulomb level: it stays put."""
    offset = InputOffset(x=OffsetAxis(0.15), y=OffsetAxis(0.1))
    plant = Plant(offset=offset)
    trace = simulate(plant, circle(), TimingLaw(2.0, "rest"), PD(**ZERO_PD), 0.2, backend=backend)
    force_n = 0.15 * GEAR_N_PER_V
    v_final = (force_n - FRICTION_N[0]) / DAMPING_N_S_PER_M[0]
    tau = MASS_NO_LOAD_KG[0] / DAMPING_N_S_PER_M[0]
    t = trace.t_s
    x = trace.q_m[0, 0] + v_final * (t - tau * (1.0 - np.exp(-t / tau)))
    moved = trace.q_m[-1, 0] - trace.q_m[0, 0]
    assert moved > 5e-3
    np.testing.assert_allclose(trace.q_m[:, 0] - trace.q_m[0, 0], x - x[0], rtol=0, atol=2e-3 * moved)
    assert np.abs(trace.q_m[:, 1] - trace.q_m[0, 1]).max() < 1e-7
    without = simulate(Plant(), circle(), TimingLaw(2.0, "rest"), PD(**ZERO_PD), 0.2, backend=backend)
    assert np.abs(without.q_m[:, 0] - without.q_m[0, 0]).max() < 1e-7


@pytest.mark.parametrize("backend", ["compiled", "reference"])
def test_offset_and_ripple_are_input_forces_of_their_formula(backend):
    """A linear offset and three ripple harmonics per axis: the loop's trace against a plain mj_step loop that
    feeds the disturbance motors the formula written out in this module (zero-gain PD)."""
    offset = InputOffset(x=OffsetAxis(0.05, 0.08), y=OffsetAxis(-0.04, -0.1))
    ripple = ForceRipple(
        x=RippleAxis(0.016, (RippleHarmonic(0.05, 0.3), RippleHarmonic(0.03, -1.0), RippleHarmonic(0.02, 2.0))),
        y=RippleAxis(0.024, (RippleHarmonic(0.06, 1.0), RippleHarmonic(0.0), RippleHarmonic(0.04, -2.5))),
    )
    trace = simulate(Plant(offset=offset, ripple=ripple), circle(), TimingLaw(2.0), PD(**ZERO_PD), 0.2, backend=backend)
    plant = Plant()
    plant.reset(trace.q_d_m[0], circle().derivatives(np.zeros(1))[1][0] * 2.0)
    q = np.empty_like(trace.q_m)
    for k in range(q.shape[0]):
        q[k] = plant.q_m
        plant.data.ctrl[plant.motor_index] = 0.0
        plant.data.ctrl[plant.disturbance_index] = offset_and_ripple_v(q[k], offset, ripple)
        mujoco.mj_step(plant.model, plant.data)
        if k == 0:
            force = plant.data.qfrc_actuator[plant.dof_index]  # the joint force, N: gear kf times the volts
            np.testing.assert_allclose(force, GEAR_N_PER_V * offset_and_ripple_v(q[0], offset, ripple), rtol=1e-12)
    np.testing.assert_allclose(trace.q_m, q, rtol=0, atol=1e-12)
    free = simulate(Plant(offset=offset), circle(), TimingLaw(2.0), PD(**ZERO_PD), 0.2, backend=backend)
    assert np.abs(free.q_m - trace.q_m).max() > 1e-6  # the ripple moved the plant


def identified_by_least_squares(fc_n: float, fs_n: float, vs_m_s: float, sigma2: float) -> tuple[float, float]:
    """The paper's identification of a LuGre axis done here: Af sign(v) + B v fitted to the steady friction
    g(v) + sigma2 v over an axis moving as on the paper's circle, v = 0.4 cos(2 t) m/s sampled in time (a
    quarter period, where v > 0)."""
    t = np.linspace(0.0, math.pi / 4.0, 20001)[:-1] + math.pi / 4.0 / 40000.0
    v = 0.4 * np.cos(2.0 * t)
    force = fc_n + (fs_n - fc_n) * np.exp(-((v / vs_m_s) ** 2)) + sigma2 * v
    (af, b), *_ = np.linalg.lstsq(np.column_stack([np.ones_like(v), v]), force, rcond=None)
    return float(af), float(b)


def test_rig_true_parameters_are_the_papers_identification_of_it():
    """M from the model, B and Af by least squares on the steady LuGre curve (done here), dN the file's offset at
    the operating point; and the identification constraint: that identification returns the paper's Af and B
    within 3 %."""
    rig = Plant.shipped("rig")
    theta = rig.true_parameters()
    np.testing.assert_allclose(theta[:2], MASS_NO_LOAD_KG / GEAR_N_PER_V, rtol=1e-12)
    for axis in range(2):
        p = lugre_parameters(rig.model, int(rig.friction_index[axis]), int(rig.dof_index[axis]))
        af, b = identified_by_least_squares(p.fc_n, p.fs_n, p.vs_m_s, p.sigma2_ns_m)
        assert theta[4 + axis] == pytest.approx(af / GEAR_N_PER_V, rel=1e-5)
        assert theta[2 + axis] == pytest.approx(b / GEAR_N_PER_V, rel=1e-5)
        assert p.fs_n > p.fc_n  # a Stribeck bump, not the paper's Coulomb model
    np.testing.assert_allclose(theta[4:6], PAPER_AF_V, rtol=IDENTIFICATION_REL)
    np.testing.assert_allclose(theta[2:4], PAPER_B_V_S_M, rtol=IDENTIFICATION_REL)
    offsets = file_properties(mujoco.MjSpec.from_file(str(default_model_path("rig")))).offset
    np.testing.assert_array_equal(theta[6:8], [offsets.x.constant_v, offsets.y.constant_v])
    assert np.abs(theta[6:8]).min() > 0.0


@pytest.mark.slow
def test_identify_on_an_excitation_of_the_rig_returns_the_papers_parameters(tmp_path):
    """The identification constraint the other way: `gantry-twin excite`'s 20 s multisine run on the rig plant
    (its LuGre friction, offset and ripple, the 0.5 um encoder) and `gantry-twin identify`'s least squares on the
    log return the paper's M within 1 %, B and Af within 3 %, and the rig's offset dN within 0.005 V."""
    from gantry_twin.sysid.identify import identify
    from gantry_twin.sysid.logs import read_log, write_log
    from gantry_twin.sysid.trajectory import design, log_of, run_on_twin

    rig = Plant.shipped("rig")
    write_log(tmp_path / "log.parquet", *log_of(run_on_twin(design(20.0), rig)))
    theta = identify([read_log(tmp_path / "log.parquet")]).theta
    np.testing.assert_allclose(theta[0:2], PAPER_M_V_S2_M, rtol=MASS_REL)
    np.testing.assert_allclose(theta[2:4], PAPER_B_V_S_M, rtol=IDENTIFICATION_REL)
    np.testing.assert_allclose(theta[4:6], PAPER_AF_V, rtol=IDENTIFICATION_REL)
    np.testing.assert_allclose(theta[6:8], rig.true_parameters()[6:8], atol=0.005)


def test_true_dn_is_the_offset_at_the_contours_mean_position():
    """With a linear part, dN1, dN2 of a run are dN(q) at the contour's mean position (the ellipse's centre
    (0, 0.1) m), where a linear dN(q) has its time mean; the paper plant's dN is 0."""
    offset = InputOffset(x=OffsetAxis(0.02, 0.05), y=OffsetAxis(0.03, 0.1))
    trace = simulate(Plant(offset=offset), paper_ellipse(), TimingLaw(3.0), PD(**ZERO_PD), 0.01)
    np.testing.assert_allclose(trace.true_theta[6:8], [0.02, 0.03 + 0.1 * 0.1 / TRAVEL_END_M], atol=1e-9)
    assert np.all(simulate(Plant(), circle(), TimingLaw(2.0), PD(**ZERO_PD), 0.01).true_theta[6:8] == 0.0)


def test_the_shipped_rig_is_physically_plausible():
    """Pre-sliding Fc / sigma0 in [0.1, 50] um, Fs / Fc in [1, 2], vs in [0.1, 50] mm/s, sigma1 at most critical,
    |dN| <= 0.15 V with at most 0.1 V over the half travel, ripple peak <= 0.1 V (docs/rig-plant.md)."""
    rig = Plant.shipped("rig")
    for axis, name in enumerate(("x", "y")):
        p = lugre_parameters(rig.model, int(rig.friction_index[axis]), int(rig.dof_index[axis]))
        assert 0.1e-6 <= p.fc_n / p.sigma0_n_m <= 50e-6
        assert 1.0 <= p.fs_n / p.fc_n <= 2.0
        assert 0.1e-3 <= p.vs_m_s <= 50e-3
        assert p.sigma1_ns_m <= 2.0 * math.sqrt(p.sigma0_n_m * MASS_NO_LOAD_KG[axis])
        o, r = getattr(rig.offset, name), getattr(rig.ripple, name)
        assert abs(o.constant_v) <= 0.15 and abs(o.half_travel_v) <= 0.1
        assert 0.0 < sum(h.amplitude_v for h in r.harmonics) <= 0.1
    assert rig.model.dof_frictionloss[rig.dof_index].max() == 0.0  # friction counts once, in LuGre


def test_a_scenario_selects_the_rig_or_the_paper_plant():
    rig = build(load_scenario(shipped("no_load_circle")))  # the default machine
    paper = build(load_scenario(shipped("no_load_circle"), ["plant.model=paper"]))
    assert load_scenario(shipped("no_load_circle")).plant.model == "rig"
    assert rig.plant.friction.lugre and rig.plant.offset != InputOffset() and rig.plant.ripple != ForceRipple()
    assert not paper.plant.friction.lugre and paper.plant.offset == InputOffset()
    assert paper.plant.ripple == ForceRipple() and np.all(paper.plant.true_parameters()[6:8] == 0.0)
    np.testing.assert_array_equal(rig.plant.true_parameters(), Plant.shipped("rig").true_parameters())
    offset = build(load_scenario(shipped("no_load_circle"), ["plant.model=rig", "plant.offset.x.constant_v=0.01"]))
    assert offset.plant.offset.x.constant_v == 0.01 and offset.plant.offset.y.constant_v == 0.0
    assert offset.plant.friction.lugre  # the file's friction stays
    with pytest.raises(ScenarioError) as both:
        load_scenario(shipped("no_load_circle"), ["plant.model=rig", "plant.file=models/gantry.xml"])
    assert both.value.field == "plant.file"
    own = load_scenario(shipped("no_load_circle"), [f"plant.file={default_model_path('paper')}"])
    assert own.plant.model is None and build(own).plant.offset == InputOffset()  # a file alone: no default model


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: OffsetAxis(0.2), "offset.constant_v: must be in [-0.15, 0.15] V, got 0.2"),
        (lambda: OffsetAxis(0.0, -0.11), "offset.half_travel_v: must be in [-0.1, 0.1] V, got -0.11"),
        (lambda: RippleHarmonic(0.12), "harmonic.amplitude_v: must be in [0, 0.1] V, got 0.12"),
        (lambda: RippleAxis(0.016, (RippleHarmonic(0.06), RippleHarmonic(0.05))), "at most 0.1 V, got 0.11"),
        (lambda: RippleAxis(0.016, (RippleHarmonic(0.01),) * 4), "at most 3 harmonics, got 4"),
        (lambda: RippleAxis(0.0001), "ripple.pitch_m: must be in [0.001, 1] m, got 0.0001"),
        (lambda: PlantSettings(model="rig", file="plant.xml"), "give a model file or model: rig, not both"),
    ],
)
def test_bad_plant_settings_are_one_line_errors(make, message):
    with pytest.raises(ValueError) as error:
        make()
    assert message in str(error.value) and "\n" not in str(error.value)


@pytest.mark.parametrize(
    ("numerics", "message"),
    [
        ('<numeric name="x_input_offset" data="0.05 0"/>', "numeric y_input_offset: missing"),
        (
            '<numeric name="x_input_offset" data="0.05 0 1"/><numeric name="y_input_offset" data="0"/>',
            "numeric x_input_offset: 1 to 2 values, got 3",
        ),
        (
            '<numeric name="x_force_ripple" data="0.016 0.05"/><numeric name="y_force_ripple" data="0.016"/>',
            "pitch_m then (amplitude_v, phase_rad) pairs, got 2 values",
        ),
        (
            '<numeric name="x_input_offset" data="0.3"/><numeric name="y_input_offset" data="0"/>',
            "offset.constant_v: must be in [-0.15, 0.15] V, got 0.3",
        ),
    ],
)
def test_a_model_files_bad_numerics_are_refused(tmp_path, numerics, message):
    path = tmp_path / "plant.xml"
    path.write_text(f'<mujoco><include file="{default_model_path()}"/><custom>{numerics}</custom></mujoco>')
    with pytest.raises(ValueError) as error:
        Plant(model_path=path)
    assert message in str(error.value)
