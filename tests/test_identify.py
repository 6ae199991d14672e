"""Identification from logs (docs/logs.md): the regression against an independent simulation, the plant file,
the command, and the acceptance on twins with random parameters (slow)."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from gantry_twin.cli import main
from gantry_twin.loop.simulate import simulate
from gantry_twin.paths.contours import TimingLaw, paper_ellipse
from gantry_twin.plant.model import Plant
from gantry_twin.scenario import build, load_scenario
from gantry_twin.sysid.identify import identify, plant_xml
from gantry_twin.sysid.logs import Log, read_log, write_log
from gantry_twin.sysid.trajectory import design, log_of, random_plant, run_on_twin

from .helpers import spec_theta

ENCODER_M = 0.5e-6


def _exact_step(q: float, v: float, u: float, m: float, b: float, af: float, h: float) -> tuple[float, float]:
    """One sample of m x'' + b x' + af sign(x') = u, u held: the exponential solution piece by piece (a stop
    where the velocity reaches zero, stick while |u| <= af)."""
    left = h
    while left > 0.0:
        if v == 0.0 and abs(u) <= af:
            return q, 0.0
        s = math.copysign(1.0, v if v != 0.0 else u)
        v_inf, tau = (u - af * s) / b, m / b
        if v != 0.0 and v_inf * s < 0.0:  # decelerating through zero: stop there
            t0 = tau * math.log((v - v_inf) / -v_inf)
            if t0 < left:
                q += v_inf * t0 + (v - v_inf) * tau * (1.0 - math.exp(-t0 / tau))
                v, left = 0.0, left - t0
                continue
        e = math.exp(-left / tau)
        q += v_inf * left + (v - v_inf) * tau * (1.0 - e)
        v, left = v_inf + (v - v_inf) * e, 0.0
    return q, v


def ode_log(theta: np.ndarray, duration_s: float = 6.0, ts: float = 2e-4) -> Log:
    """The paper's model M x'' + B x' + Af sign(x') = u (with stick) solved exactly per sample, open loop
    under a sum of cosines, positions quantised to the encoder: no MuJoCo, no estimation code."""
    n = int(round(duration_s / ts))
    t = np.arange(n) * ts
    u = np.zeros((n, 2))
    for amp, f in ((1.0, 0.7), (1.5, 1.9), (2.0, 4.3)):
        u += amp * np.cos(2 * np.pi * f * t)[:, None] * np.array([0.4, 1.0])
    out = np.empty((n, 2))
    for axis in range(2):
        q = v = 0.0
        m, b, af = (float(theta[j + axis]) for j in (0, 2, 4))
        for k in range(n):
            out[k, axis] = q
            q, v = _exact_step(q, v, float(u[k, axis]), m, b, af, ts)
    return Log("ode", t, u, np.round(out / ENCODER_M) * ENCODER_M, None, ts)


def test_regression_recovers_an_independent_simulation():
    theta = spec_theta(3.0)
    result = identify([ode_log(theta)])
    err = (result.theta[:6] - theta[:6]) / theta[:6]
    assert np.abs(err).max() < 0.005, err
    assert np.abs(result.theta[6:]).max() < 1e-3
    assert np.all(result.ci95[:, 0] < result.theta) and np.all(result.theta < result.ci95[:, 1])


def test_plant_file_holds_the_identified_parameters(tmp_path):
    theta = np.array([0.21, 0.63, 0.41, 0.88, 0.07, 0.19, 0.0, 0.0])
    path = tmp_path / "plant.xml"
    path.write_text(plant_xml(theta, "test"))
    np.testing.assert_allclose(Plant(model_path=path).true_parameters(), theta, rtol=1e-5, atol=1e-15)
    with pytest.raises(ValueError, match="M2"):
        plant_xml(np.array([0.5, 0.4, 0.5, 0.7, 0.1, 0.15, 0.0, 0.0]))


def test_identify_command_writes_parameters_plant_and_fit_report(tmp_path):
    theta = spec_theta(0.0)
    log = ode_log(theta, duration_s=4.0)
    write_log(tmp_path / "log.csv", log.t_s, log.u_v, log.q_m, None)
    out = tmp_path / "id"
    assert main(["identify", str(tmp_path / "log.csv"), "--out", str(out)]) == 0
    data = json.loads((out / "identified.json").read_text())
    for name in ("M1", "M2", "B1", "B2", "Af1", "Af2"):
        p = data["parameters"][name]
        lo, hi = p["ci95"]
        assert lo <= p["value"] <= hi
    assert (out / "fit_0.png").stat().st_size > 1000 and (out / "fit_report.md").is_file()
    fit = data["fit"][0]["rms_um"]
    assert max(fit.values()) < 1000.0  # the replay follows the log (the ODE's friction is MuJoCo's to within its
    # soft constraint): not a drift of millimetres
    scenario_file = tmp_path / "machine.yaml"
    scenario_file.write_text("plant: {file: id/plant.xml}\n")
    built = build(load_scenario(scenario_file), str(scenario_file))
    identified = [data["parameters"][n]["value"] for n in ("M1", "M2", "B1", "B2", "Af1", "Af2")]
    np.testing.assert_allclose(built.plant.true_parameters()[:6], identified, rtol=1e-5)  # MJCF text: 6 digits


@pytest.mark.parametrize(("entry", "value"), [(2, -47.72), (5, -10.37), (0, 0.0), (1, -0.5)])
def test_an_unphysical_fit_exits_2_with_the_reason_and_what_the_log_needs(tmp_path, capsys, monkeypatch, entry, value):
    """Negative damping or friction, a mass <= 0: exit 2, one line naming the log, the entry and what a log needs,
    nothing written (no plant.xml, no --out)."""
    from gantry_twin.cli import identify as identify_command
    from gantry_twin.sysid.identify import LOG_NEEDS, THETA_UNITS

    theta = spec_theta(0.0)
    log = ode_log(theta, duration_s=1.0)
    write_log(tmp_path / "log.csv", log.t_s, log.u_v, log.q_m, None)

    def unphysical(logs, settings):  # noqa: ANN001, ANN202
        result = identify(logs, settings)
        result.theta[entry] = value
        return result

    monkeypatch.setattr(identify_command, "identify", unphysical)
    out = tmp_path / "id"
    capsys.readouterr()
    assert main(["identify", str(tmp_path / "log.csv"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    name = ("M1", "M2", "B1", "B2", "Af1", "Af2")[entry]
    assert len(err) == 1 and err[0].startswith(
        f"gantry-twin: error: {tmp_path / 'log.csv'}: cannot identify this machine"
    )
    assert f"{name} = {value:.4g} {THETA_UNITS[entry]}" in err[0] and err[0].endswith(LOG_NEEDS)
    assert not out.exists()


def _another_machine(tmp_path, theta: np.ndarray, polarity_x: float = 1.0) -> str:
    """A CSV log of 1 s of the paper's model (ode_log, no MuJoCo) on a machine of ``theta`` whose X amplifier has
    ``polarity_x`` (-1: +1 V pushes -x); its path."""
    log = ode_log(theta, duration_s=1.0)
    u = log.u_v * np.array([polarity_x, 1.0])
    write_log(tmp_path / "other.csv", log.t_s, u, log.q_m, None)
    return str(tmp_path / "other.csv")


@pytest.mark.parametrize("machine", ["reversed_x", "x_heavier_than_y"])
def test_a_log_of_another_machine_exits_2_saying_why_it_cannot_identify_this_model(tmp_path, capsys, machine):
    """Logs a fit of this machine's model cannot come from: a machine whose X amplifier has the other polarity (the
    fit's M1, B1, Af1 come out as that machine's negated), and one whose X carriage is heavier than the Y axis that
    should carry it. Exit 2, one line: the log, the fit's values (checked against the simulated machine's) and why
    no machine of this kind has them, and what the log would need (docs/logs.md); nothing written."""
    from gantry_twin.sysid.identify import LOG_NEEDS

    theta = spec_theta(0.0)
    if machine == "reversed_x":
        path = _another_machine(tmp_path, theta, polarity_x=-1.0)
        expected, why = {"M1": -theta[0], "B1": -theta[2], "Af1": -theta[4]}, "a mass must be > 0"
    else:
        theta[0], theta[1] = 0.6, 0.5
        path = _another_machine(tmp_path, theta)
        expected, why = {"M1": 0.6, "M2": 0.5}, "M2 must exceed M1"
    out = tmp_path / "id"
    capsys.readouterr()
    assert main(["identify", path, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"gantry-twin: error: {path}: cannot identify this machine's model: ")
    given = {name: float(value) for name, value in re.findall(r"\b(M[12]|B[12]|Af[12]) = (-?[0-9.e+-]+)", err[0])}
    assert set(given) == set(expected), err[0]
    for name, value in expected.items():
        assert given[name] == pytest.approx(value, rel=2e-3), (name, err[0])
    assert why in err[0] and err[0].endswith(LOG_NEEDS) and "Traceback" not in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other.csv"]


def _errors(result, truth):
    err = np.abs(result.theta[:6] - truth[:6]) / truth[:6]
    return err[:2].max(), err[2:6].max()


@pytest.mark.slow
@pytest.mark.parametrize("seed", [11, pytest.param(12, marks=pytest.mark.exhaustive)])  # a second twin: -m exhaustive
def test_acceptance_twenty_second_excitation(seed, tmp_path):
    """The acceptance: a 20 s excitation on a random twin (0.5 um encoder): M within 1 %, B and Af within 3 %."""
    plant = random_plant(np.random.default_rng(seed))
    truth = plant.true_parameters()
    write_log(tmp_path / "log.parquet", *log_of(run_on_twin(design(20.0), plant)))
    m_err, other_err = _errors(identify([read_log(tmp_path / "log.parquet")]), truth)
    assert m_err < 0.01 and other_err < 0.03, (m_err, other_err)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [21, pytest.param(22, marks=pytest.mark.exhaustive)])  # a second twin: -m exhaustive
def test_acceptance_thirty_second_ellipse(seed, tmp_path):
    """The acceptance: a 30 s log of the paper's ellipse under DIARC on a random twin: M within 2 %, B and Af
    within 5 %."""
    from gantry_twin.controllers import create

    plant = random_plant(np.random.default_rng(seed))
    truth = plant.true_parameters()
    trace = simulate(plant, paper_ellipse(), TimingLaw(3.0), create("diarc"), duration_s=30.0)
    write_log(tmp_path / "log.parquet", *log_of(trace))
    m_err, other_err = _errors(identify([read_log(tmp_path / "log.parquet")]), truth)
    assert m_err < 0.02 and other_err < 0.05, (m_err, other_err)
