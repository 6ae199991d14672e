"""``gantry-twin calibrate``: it recovers a plant it did not see, and a bad calibration file is one line, exit 2,
nothing written."""

from __future__ import annotations

import json
import math
import sys

import pytest
import yaml

from gantry_twin.calibration import calibration_file, load_calibration, lugre_fields, plan
from gantry_twin.calibration.fit import scenario_of
from gantry_twin.cli import main
from gantry_twin.metrics import contour_metrics
from gantry_twin.plant.friction import identified_af_b
from gantry_twin.run import execute
from gantry_twin.scenario import build, load_scenario, shipped

#: Short runs: the metric window fitted to them (the loop is causal).
SHORT = {"plant.model": "rig", "duration_s": 2.5, "window_s": [0.5, 2.5], "estimates_window_s": [1.5, 2.5]}
TRUE_DN = (0.03, -0.04)
TRUE_RIPPLE_V = 0.03
#: The measured runs: the circle under two controllers. Its 2.5 s runs move both axes through a reversal, and the two
#: controllers' different errors separate the offsets from the ripple: the fit meets every tolerance below from its
#: 37th evaluation on (the ellipse's runs, once targets too, doubled each evaluation's cost and added no accuracy).
CASES = [("no_load_circle", c) for c in ("darc", "drc")]


def _ripple(amplitude_v: float) -> dict:
    return {a: {"pitch_m": 0.016, "harmonics": [{"amplitude_v": amplitude_v}]} for a in ("x", "y")}


def _overrides(values: dict) -> list[str]:
    return [f"{k}={json.dumps(v)}" for k, v in values.items()]


@pytest.fixture(scope="module")
def measured() -> list[dict]:
    """The 'machine': the rig plant with offsets and a ripple the calibration does not see."""
    truth = {
        **SHORT,
        "plant.offset.x.constant_v": TRUE_DN[0],
        "plant.offset.y.constant_v": TRUE_DN[1],
        "plant.ripple": _ripple(TRUE_RIPPLE_V),
    }
    targets = []
    for scenario, controller in CASES:
        run = load_scenario(shipped(scenario), _overrides(truth), controller)
        m = contour_metrics(execute(build(run, scenario)), run.metric_window_s)
        targets.append({"scenario": scenario, "controller": controller, "rms_um": m.rms_um, "max_um": m.max_um})
    return targets


def _spec(targets: list[dict]) -> dict:
    ripple_fields = [f"plant.ripple.{a}.harmonics.0.amplitude_v" for a in ("x", "y")]
    return {
        "description": "recover offsets and a ripple",
        "base": {**SHORT, "plant.ripple": _ripple(0.05)},
        "targets": targets,
        "free": [
            {"name": "dN1", "field": "plant.offset.x.constant_v", "range": [-0.1, 0.1], "start": 0.0},
            {"name": "dN2", "field": "plant.offset.y.constant_v", "range": [-0.1, 0.1], "start": 0.0},
            {"name": "ripple", "field": ripple_fields, "range": [0.0, 0.08], "start": 0.05},
        ],
        "optimiser": {"evaluations": 40},
    }


@pytest.mark.slow
def test_calibrate_recovers_a_plant_it_did_not_see(tmp_path, measured, capsys):
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump(json.loads(json.dumps(_spec(measured))), sort_keys=False))  # no shared objects
    out = tmp_path / "fit"
    assert main(["calibrate", str(spec), "--out", str(out), "--workers", "2"]) == 0
    fit = json.loads((out / "fit.json").read_text())
    values = fit["values"]
    print(
        f"recovered {values} (true dN {TRUE_DN}, ripple {TRUE_RIPPLE_V}); cost {fit['cost']:.3g}",
        file=sys.stderr,
    )
    assert abs(values["dN1"] - TRUE_DN[0]) <= 0.01
    assert abs(values["dN2"] - TRUE_DN[1]) <= 0.01
    assert abs(values["ripple"] / TRUE_RIPPLE_V - 1.0) <= 0.20
    for residual in fit["residuals"]:
        for what in ("rms_um", "max_um"):
            assert abs(residual[what]["error_pct"]) <= 5.0, residual
    lines = (out / "evaluations.jsonl").read_text().splitlines()
    assert len(lines) == fit["evaluations"] >= 10
    assert json.loads(lines[fit["best_evaluation"]])["cost"] == fit["cost"]
    # The plant file runs as the fit's best point: plant.file gives the same numbers.
    scenario, controller = CASES[1]
    short = {k: v for k, v in SHORT.items() if k != "plant.model"}
    run = load_scenario(shipped(scenario), [*_overrides(short), f"plant.file={out / 'plant.xml'}"], controller)
    m = contour_metrics(execute(build(run, scenario)), run.metric_window_s)
    assert m.rms_um == pytest.approx(fit["residuals"][1]["rms_um"]["twin"], rel=1e-6)  # 12 digits in the file


def test_the_constraint_gives_the_identification_back():
    """Fc and sigma2 by the closed form: friction.identified_af_b returns the spec's Af and B."""
    for r, vs in ((1.0, 0.005), (1.6, 0.011), (2.0, 0.03)):
        p = lugre_fields({"fs_over_fc": r, "vs_m_s": vs, "presliding_m": 3e-6, "zeta": 0.05}, 0.1, 0.5, 8.28, 69.0)
        af, b = identified_af_b(p["fc_n"], p["fs_n"], vs, p["sigma2_ns_m"])
        assert float(af) / 69.0 == pytest.approx(0.1, rel=1e-9)
        assert float(b) / 69.0 == pytest.approx(0.5, rel=1e-9)
        assert p["fs_n"] / p["fc_n"] == pytest.approx(r)
        assert p["fc_n"] / p["sigma0_n_m"] == pytest.approx(3e-6)
        assert p["sigma1_ns_m"] == pytest.approx(0.05 * 2 * math.sqrt(p["sigma0_n_m"] * 8.28))


def test_the_shipped_example_is_found_by_name_and_plans():
    path = calibration_file("paper_circle_set1")
    made = plan(load_calibration(path), str(path))
    start = {f.label: f.start_value for f in made.spec.free}
    theta = build(scenario_of(made, 0, start), str(path)).plant.true_parameters()
    assert theta[:6] == pytest.approx([0.12, 0.5, 0.5, 0.7, 0.1, 0.15], rel=1e-6)  # the identification constraint
    assert list(theta[6:]) == pytest.approx([start["dN1"], start["dN2"]])


def test_an_unreachable_scheduler_is_exit_2_nothing_written(tmp_path, capsys):
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump(json.loads(json.dumps(GOOD)), sort_keys=False))
    out = tmp_path / "out"
    assert main(["calibrate", str(spec), "--out", str(out), "--scheduler", "tcp://127.0.0.1:9"]) == 2
    assert "cannot connect" in capsys.readouterr().err
    assert not out.exists()


GOOD = {
    "base": SHORT,
    "targets": [{"scenario": "no_load_circle", "controller": "drc", "rms_um": 5.0}],
    "free": [{"field": "plant.offset.x.constant_v", "range": [0.0, 0.1]}],
}


def _bad(**change) -> dict:
    spec = json.loads(json.dumps(GOOD))
    for path, value in change.items():
        node = spec
        *parents, last = path.split("__")
        for p in parents:
            node = node[int(p)] if isinstance(node, list) else node[p]
        node[last] = value
    return spec


@pytest.mark.parametrize(
    ("spec", "words"),
    [
        (_bad(free__0__field="plant.offset.x.constnt_v"), ["free[0]", "constnt_v", "constant_v"]),
        (_bad(free__0__range=[0.1, 0.1]), ["free[0].range", "low must be below high"]),
        (_bad(free__0__range=[0.0, 0.3]), ["free[0].range", "0.3", "[-0.15, 0.15] V"]),
        (_bad(targets__0__rms_um=-2.0), ["targets[0].rms_um", "(0, inf] um", "-2"]),
        (_bad(targets__0__controller="nope"), ["targets[0]", "nope"]),
        (_bad(optimiser={"evaluations": 0}), ["optimiser.evaluations", "[1, 10000]"]),
        (_bad(tragets=[]), ["tragets", "allowed"]),
        (
            _bad(identification={"B": [0.5, 0.7], "Af": [0.1, 0.15]}, base={**SHORT, "plant.friction.x.fc_n": 5.0}),
            ["base.plant.friction.x.fc_n", "identification constraint"],
        ),
    ],
)
def test_a_bad_spec_is_one_line_exit_2_nothing_written(tmp_path, capsys, spec, words):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(json.loads(json.dumps(spec)), sort_keys=False))
    out = tmp_path / "out"
    assert main(["calibrate", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert str(path) in err
    for word in words:
        assert word in err, (word, err)
    assert not out.exists()


def test_a_missing_file_is_one_line_exit_2_nothing_written(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["calibrate", str(tmp_path / "absent.yaml"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no such file" in err and "absent.yaml" in err
    assert not out.exists()
