"""The scenario schema: defaults, shipped files, overrides, disturbances, options."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gantry_twin.controllers import DARC, DIARC, DRC, RECOMMENDED_ESTIMATOR, EstimatorSettings, register, unregister
from gantry_twin.controllers.pd import PD
from gantry_twin.scenario import (
    Scenario,
    ScenarioError,
    apply_overrides,
    build,
    dump_yaml,
    load_scenario,
    shipped,
    shipped_scenarios,
    validate_data,
)

PAPER_NAMES = {
    "no_load_circle",
    "no_load_ellipse",
    "load_5kg_circle",
    "load_5kg_ellipse",
    "step_disturbance_circle",
    "step_disturbance_ellipse",
}


def write(tmp_path: Path, text: str, name: str = "s.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_the_six_paper_scenarios_ship():
    assert PAPER_NAMES <= {p.stem for p in shipped_scenarios()}


@pytest.mark.parametrize("name", sorted(PAPER_NAMES))
def test_shipped_scenario_validates_and_builds(name):
    scenario = load_scenario(shipped(name))
    built = build(scenario, name)
    assert scenario.name == name
    assert isinstance(built.controller, DIARC)
    assert scenario.duration_s == 30.0
    assert scenario.contour.timing.start == "on_path"


@pytest.mark.parametrize(
    ("name", "mass_kg", "rate", "window"),
    [
        ("no_load_circle", 0.0, 2.0, (math.pi, 2 * math.pi)),
        ("load_5kg_circle", 5.0, 2.0, (math.pi, 2 * math.pi)),
        ("no_load_ellipse", 0.0, 3.0, (2 * math.pi / 3, 4 * math.pi / 3)),
        ("load_5kg_ellipse", 5.0, 3.0, (2 * math.pi / 3, 4 * math.pi / 3)),
        ("step_disturbance_circle", 0.0, 2.0, (1.5, 6.5)),
        ("step_disturbance_ellipse", 0.0, 3.0, (1.5, 6.5)),
    ],
)
def test_shipped_windows_follow_spec_section_8(name, mass_kg, rate, window):
    s = load_scenario(shipped(name))
    assert s.payload.mass_kg == mass_kg
    assert s.rate_rad_s == rate
    assert s.metric_window_s == pytest.approx(window)
    period = 2 * math.pi / rate
    assert s.estimate_window_s == pytest.approx((30.0 - period, 30.0))


@pytest.mark.parametrize("contour", ["circle", "ellipse"])
def test_set3_disturbance_is_0_6_v_on_y_from_1_86_to_4_86_s(contour):
    fn = build(load_scenario(shipped(f"step_disturbance_{contour}"))).disturbance
    t = np.array([0.0, 1.8598, 1.86, 3.0, 4.8598, 4.86, 10.0])
    d = fn(t)
    assert d.shape == (7, 2)
    np.testing.assert_array_equal(d[:, 0], 0.0)
    np.testing.assert_array_equal(d[:, 1], [0, 0, 0.6, 0.6, 0.6, 0, 0])


def test_empty_mapping_gives_the_spec_defaults(tmp_path):
    s = load_scenario(write(tmp_path, "{}"))
    assert s.contour.type == "circle" and s.contour.radius_m == 0.2 and s.rate_rad_s == 2.0
    assert s.controller.name == "diarc" and s.duration_s == 30.0
    assert s.sensing.quantize and s.sensing.resolution_m == 0.5e-6 and s.sensing.velocity_by_difference
    assert s.payload.mass_kg == 0.0 and s.disturbance.empty
    assert s.name == "s"
    ellipse = load_scenario(write(tmp_path, "contour: {type: ellipse}"))
    assert (ellipse.contour.semi_x_m, ellipse.contour.semi_y_m, tuple(ellipse.contour.centre_m)) == (0.2, 0.1, (0, 0.1))
    assert ellipse.rate_rad_s == 3.0


def test_rest_start_moves_the_default_window_by_the_ramp(tmp_path):
    s = load_scenario(write(tmp_path, "contour: {timing: {start: rest, ramp_s: 0.5}}"))
    assert s.metric_window_s == pytest.approx((0.5 + math.pi, 0.5 + 2 * math.pi))


def test_ramp_and_sine_events_against_direct_formulas(tmp_path):
    text = """
disturbance:
  x:
    - {type: ramp, from_v: 0.2, to_v: 1.2, start_s: 1.0, end_s: 3.0}
    - {type: step, value_v: -0.1, start_s: 2.0}
  y:
    - {type: sine, amplitude_v: 0.5, frequency_hz: 2.0, phase_rad: 0.3, start_s: 0.5, end_s: 1.5}
"""
    fn = build(load_scenario(write(tmp_path, text))).disturbance
    t = np.linspace(0.0, 4.0, 4001)
    d = fn(t)
    ramp = np.where((t >= 1.0) & (t < 3.0), 0.2 + (t - 1.0) / 2.0, 0.0)
    step = np.where(t >= 2.0, -0.1, 0.0)
    sine = np.where((t >= 0.5) & (t < 1.5), 0.5 * np.sin(4 * np.pi * t + 0.3), 0.0)
    np.testing.assert_allclose(d[:, 0], ramp + step, atol=1e-12)
    np.testing.assert_allclose(d[:, 1], sine, atol=1e-12)


def test_overrides_set_nested_fields_and_list_items(tmp_path):
    path = shipped("step_disturbance_circle")
    s = load_scenario(
        path,
        [
            "payload.mass_kg=5",
            "disturbance.y.0.value_v=-0.3",
            "sensing.quantize=false",
            "window_s=[2, 3]",
            "controller.options.estimator=recommended",
        ],
    )
    assert s.payload.mass_kg == 5.0
    assert s.disturbance.y[0].value_v == -0.3
    assert s.sensing.quantize is False
    assert s.metric_window_s == (2.0, 3.0)
    assert build(s).controller.estimator_settings == RECOMMENDED_ESTIMATOR


def test_override_to_null_restores_a_default_window():
    s = load_scenario(shipped("step_disturbance_circle"), ["window_s="])
    assert s.metric_window_s == pytest.approx((math.pi, 2 * math.pi))


@pytest.mark.parametrize("item", ["payload.mass_kg", "=5", "payload..mass_kg=5", "disturbance.y.7.value_v=1"])
def test_bad_override_syntax_is_a_scenario_error(item):
    with pytest.raises(ScenarioError, match="--set"):
        apply_overrides({"disturbance": {"y": [{}]}}, [item], "f.yaml")


def test_controller_switch_drops_the_other_controllers_options(tmp_path):
    path = write(tmp_path, "controller: {name: diarc, options: {estimator: recommended}}")
    assert isinstance(build(load_scenario(path, controller="darc")).controller, DARC)
    kept = build(load_scenario(path, controller="diarc")).controller
    assert kept.estimator_settings == RECOMMENDED_ESTIMATOR


def test_builtin_controller_options_reach_the_factory(tmp_path):
    text = """
controller:
  name: diarc
  options:
    gains: {lambda_1_s: [80, 20], ks_v_s_m: [90, 50]}
    estimator: {filter_hz: [60, 40], least_squares: {nu: 0.2}}
"""
    c = build(load_scenario(write(tmp_path, text))).controller
    assert c.gains.lambda_1_s == (80.0, 20.0) and c.gains.ks_v_s_m == (90.0, 50.0)
    assert c.estimator_settings.filter_hz == (60.0, 40.0)
    assert c.estimator_settings.least_squares.nu == 0.2
    assert c.estimator_settings.least_squares.kappa == EstimatorSettings().least_squares.kappa
    darc = build(load_scenario(write(tmp_path, "controller: {name: darc, options: {gamma: [1,2,3,4,5,6,7,8]}}")))
    np.testing.assert_array_equal(darc.controller.gamma, np.arange(1, 9))
    drc = build(load_scenario(write(tmp_path, "controller: {name: drc}"))).controller
    assert isinstance(drc, DRC)
    pd_c = build(load_scenario(write(tmp_path, "controller: {name: pd, options: {kp_v_m: [5000, 6000]}}")))
    assert isinstance(pd_c.controller, PD) and pd_c.controller.kp_v_m == (5000.0, 6000.0)


class _Plugin:
    def __init__(self, gain: float = 1.0) -> None:
        self.gain = gain

    def reset(self, context):  # noqa: ANN001
        pass

    def update(self, measurement, reference):  # noqa: ANN001
        return np.zeros(2)

    def state_for_logging(self):
        return {}


def test_plugin_controller_options_pass_through(tmp_path):
    register("test_plugin_scn", _Plugin)
    try:
        c = build(load_scenario(write(tmp_path, "controller: {name: test_plugin_scn, options: {gain: 3}}")))
        assert c.controller.gain == 3
        bad = load_scenario(write(tmp_path, "controller: {name: test_plugin_scn, options: {gains: 3}}"))
        with pytest.raises(ScenarioError, match="controller.options"):
            build(bad, "p.yaml")
    finally:
        unregister("test_plugin_scn")


@pytest.mark.parametrize("name", sorted(PAPER_NAMES))
def test_resolved_scenario_round_trips(name, tmp_path):
    s = load_scenario(shipped(name))
    resolved = s.resolved()
    path = write(tmp_path, dump_yaml(resolved), "resolved.yaml")
    again = load_scenario(path)
    assert again.resolved() == resolved
    assert isinstance(again, Scenario)


def test_validate_data_reports_the_first_problem_and_counts_the_rest():
    with pytest.raises(ScenarioError) as info:
        validate_data({"payload": {"mass_kg": -1, "offset_m": [9, 0, 0]}}, "x.yaml")
    text = str(info.value)
    assert text.startswith("x.yaml: payload.mass_kg: must be in [0, 20] kg")
    assert "1 more problem" in text


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({}, "index '99' is out of range: disturbance.y has no items"),
        ({"disturbance": {"y": []}}, "index '99' is out of range: disturbance.y has no items"),
        (
            {"disturbance": {"y": [{"type": "step", "value_v": 1}]}},
            "index '99' is out of range: disturbance.y has 1 item (index 0..0)",
        ),
    ],
)
def test_set_index_out_of_range_says_so_and_the_valid_range(data, message):
    """``--set disturbance.y.99.value_v=1`` once answered "input should be a valid list"."""
    with pytest.raises(ScenarioError) as info:
        apply_overrides(data, ["disturbance.y.99.value_v=1"], "f.yaml")
    assert (info.value.field, info.value.message) == ("--set disturbance.y.99.value_v", message)


# ``name`` (and ``outputs.dir``) is a label that names one directory under runs/, never a path.
NOT_LABELS = ["../x", "/some/dir", "a/b", "..", ".", ".hidden", "-rf", "", "n" * 65, "a b", "a\\b", "caf\u00e9", "x\n"]


@pytest.mark.parametrize("label", NOT_LABELS)
@pytest.mark.parametrize("field", ["name", "outputs.dir"])
def test_name_and_outputs_dir_are_labels_not_paths(field, label):
    head, _, tail = field.partition(".")
    data = {head: {tail: label}} if tail else {head: label}
    with pytest.raises(ScenarioError) as info:
        validate_data(data, "f.yaml")
    assert info.value.field == field
    assert info.value.message.startswith("must be a label, not a path: 1 to 64 letters A-Z a-z, digits, '_', '-'")


@pytest.mark.parametrize("label", ["no_load_circle", "run-1.v2", "_x", "3kg", "n" * 64])
def test_labels_are_accepted(label):
    s = validate_data({"name": label, "outputs": {"dir": label}}, "f.yaml")
    assert s.name == s.outputs.dir == label


@pytest.mark.parametrize(
    ("file_name", "name"), [("my run.yaml", "my_run"), ("...yaml", "_.."), ("-x.yaml", "_-x"), ("ok.v2.yaml", "ok.v2")]
)
def test_a_name_taken_from_the_file_name_is_made_a_label(tmp_path, file_name, name):
    assert load_scenario(write(tmp_path, "{}", file_name)).name == name


def test_default_output_directories_stay_under_runs(tmp_path, monkeypatch):
    """A run whose scenario says ``outputs.dir`` writes into runs/<dir>/ of the working directory and nowhere else."""
    from gantry_twin.cli import app as cli

    monkeypatch.chdir(tmp_path)
    path = write(tmp_path, "name: n\noutputs: {dir: here, trace: false}\nduration_s: 0.01\nwindow_s: [0, 0.01]\n")
    code = cli.main(["run", str(path), "--controller", "pd", "--set", "estimates_window_s=[0, 0.01]", "--no-progress"])
    assert code == 0
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.glob("*")) == ["runs", "s.yaml"]
    assert (tmp_path / "runs" / "here" / "latest" / "summary.json").is_file()


def test_exponent_without_a_decimal_point_is_a_number():
    """PyYAML (YAML 1.1) alone reads 1e-300 as a string; the scenario reader reads a number and range-checks it."""
    from gantry_twin.scenario.loading import load_yaml

    assert load_yaml("a: 1e-300\nb: [5e7, -2E-3, +1e2]\nc: e5") == {"a": 1e-300, "b": [5e7, -2e-3, 1e2], "c": "e5"}


@pytest.mark.parametrize(
    ("duration_s", "start", "metric", "estimates"),
    [
        (30.0, "on_path", (math.pi, 2 * math.pi), (30.0 - math.pi, 30.0)),  # the paper's windows
        (5.0, "on_path", (5.0 - math.pi, 5.0), (5.0 - math.pi, 5.0)),  # [T, 2T] past the end: the last period
        (2.0, "rest", (0.5, 2.0), (0.5, 2.0)),  # shorter than T: the run after the ramp
    ],
)
def test_default_windows_follow_a_short_run(duration_s, start, metric, estimates):
    """A quick `--set duration_s=5` runs without window overrides; the rule is the documented one."""
    scenario = load_scenario(shipped("no_load_circle"), [f"duration_s={duration_s}", f"contour.timing.start={start}"])
    assert scenario.metric_window_s == pytest.approx(metric)
    assert scenario.estimate_window_s == pytest.approx(estimates)
