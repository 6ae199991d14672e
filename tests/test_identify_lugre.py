"""LuGre identification from logs (issue 17): the steady-curve fit against a curve written out here, and the
command on a LuGre twin drawn at random (the acceptance, one seed; the many-seed study:
benchmarks/bench_identify_lugre.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gantry_twin.cli import main
from gantry_twin.excite import design, log_of, random_lugre_plant, run_on_twin
from gantry_twin.identify_lugre import fit_steady
from gantry_twin.logs import write_log
from gantry_twin.scenario import build, load_scenario


def test_steady_fit_recovers_a_stribeck_curve():
    """sign(v) (Fc + (Fs - Fc) exp(-(v/vs)^2)) + sigma2 v at log-spaced speeds both ways, 0.5 % noise, 100 draws:
    each value within 3 %, and the 95 % intervals miss the truth in at most 15 % of the draws (measured: up to
    about 9 %, the heteroscedasticity-consistent covariance of 80 bins is a little optimistic)."""
    fc, fs, vs, sigma2 = 7.0, 10.5, 0.006, 35.0
    truth = np.array([fc, fs, vs, sigma2])
    speed = np.geomspace(3e-4, 0.4, 40)
    v = np.concatenate([-speed, speed])
    exact = np.sign(v) * (fc + (fs - fc) * np.exp(-((v / vs) ** 2))) + sigma2 * v
    missed = np.zeros(4)
    draws = 100
    for seed in range(draws):
        force = exact * (1.0 + 0.005 * np.random.default_rng(seed).standard_normal(v.size))
        values, ci = fit_steady(v, force, guess=(8.0, 30.0))
        np.testing.assert_allclose(values, truth, rtol=0.03)
        missed += (truth < ci[:, 0]) | (ci[:, 1] < truth)
    assert np.all(missed / draws <= 0.15), missed


def _circle_rms_um(plant) -> float:
    from gantry_twin.controllers import create
    from gantry_twin.paths import TimingLaw, circle
    from gantry_twin.simulate import simulate

    trace = simulate(plant, circle(), TimingLaw(2.0), create("diarc"), duration_s=2.0 * np.pi)
    n = trace.filled
    keep = trace.t_s[:n] >= np.pi
    return float(np.sqrt(np.mean(trace.eps_c_m[:n][keep] ** 2)) * 1e6)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1])
def test_acceptance_lugre_twin(seed, tmp_path):
    """Issue 17 on a random LuGre twin (0.5 um encoder), 20 s excitation: Fc, sigma2, Fs within 10 %, vs and
    sigma0 within 30 % (the many-seed study, docs/logs.md, says how often), and the identified plant
    (plant.yaml in a scenario) reproduces a held-out circle's rms contour error within 15 %."""
    plant = random_lugre_plant(np.random.default_rng(seed))
    truth = plant.lugre_parameters()
    write_log(tmp_path / "log.parquet", *log_of(run_on_twin(design(20.0), plant)))
    out = tmp_path / "id"
    assert main(["identify", str(tmp_path / "log.parquet"), "--out", str(out), "--friction", "lugre"]) == 0
    data = json.loads((out / "identified.json").read_text())
    for axis, true in zip("xy", truth, strict=True):
        found = {name: p["value"] for name, p in data["lugre"][axis].items()}
        err = {name: abs(found[name] / getattr(true, name) - 1.0) for name in found}
        assert max(err["fc_n"], err["fs_n"], err["sigma2_ns_m"]) < 0.10, (axis, err)
        assert max(err["vs_m_s"], err["sigma0_n_m"]) < 0.30, (axis, err)
    scenario_file = tmp_path / "machine.yaml"
    scenario_file.write_text((out / "plant.yaml").read_text().replace("file: plant.xml", "file: id/plant.xml"))
    identified = build(load_scenario(scenario_file), str(scenario_file)).plant
    assert identified.friction.lugre
    true_rms, identified_rms = _circle_rms_um(plant), _circle_rms_um(identified)
    assert abs(identified_rms / true_rms - 1.0) < 0.15, (true_rms, identified_rms)
