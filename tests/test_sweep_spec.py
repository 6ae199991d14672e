"""Sweep files (docs/sweeps.md): malformed files rejected before any run, sampling, points, keys; no cluster needed."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from gantry_twin.scenario import ScenarioError
from gantry_twin.sweep import load_sweep, plan_sweep, sweeps_dir
from gantry_twin.sweep.points import override, point_key
from gantry_twin.sweep.sampling import LogUniform, Normal, Uniform, draws, unit_samples
from gantry_twin.sweep.spec import parse_sweep

from .helpers import run_main

#: A minimal sweep, 2 s points (must work as written).
MINIMAL = """\
scenario: no_load_circle            # shipped name or a path
set: {duration_s: 2, window_s: [0.5, 2], estimates_window_s: [1, 2]}   # for every point
axes:
  - field: payload.mass_kg          # any --set path
    values: [0, 2.5, 5]
  - field: controller.name
    values: [diarc, darc]
"""
HEAD = "scenario: no_load_circle\nset: {duration_s: 2, window_s: [0.5, 2], estimates_window_s: [1, 2]}\n"
AXIS = "axes:\n  - {field: payload.mass_kg, values: [0, 1]}\n"

# (id, file text, field named in the message, what the message says is allowed or wrong)
MALFORMED = [
    ("yaml_syntax", "scenario: [no_load_circle\n", "line 2", "YAML syntax error"),
    ("empty", "", "empty file", "keys: scenario, description, set, axes"),
    ("top_level_list", "- scenario\n", "top level", "keys: scenario, description, set, axes"),
    ("unknown_top_key", HEAD + "axis: []\n", "axis", "allowed: scenario, description, set, axes, random"),
    ("missing_scenario", AXIS, "scenario", "required field is missing"),
    ("no_such_scenario", "scenario: nowhere\n" + AXIS, "scenario", "no shipped scenario 'nowhere'; shipped:"),
    ("nothing_swept", HEAD, "axes", "needs axes, random or repeats"),
    ("empty_axis", HEAD + "axes:\n  - {field: payload.mass_kg, values: []}\n", "axes[0].values", "at least one"),
    ("axis_without_values", HEAD + "axes:\n  - {field: payload.mass_kg}\n", "axes[0].values", "exactly one of"),
    (
        "axis_two_ranges",
        HEAD + "axes:\n  - {field: payload.mass_kg, values: [1], linspace: {start: 0, stop: 1, num: 2}}\n",
        "axes[0].values",
        "exactly one of values, linspace, logspace (got values, linspace)",
    ),
    (
        "negative_num",
        HEAD + "axes:\n  - {field: payload.mass_kg, linspace: {start: 0, stop: 5, num: -3}}\n",
        "axes[0].linspace.num",
        "integer in [1, 100000], got -3",
    ),
    (
        "logspace_from_zero",
        HEAD + "axes:\n  - {field: payload.mass_kg, logspace: {start: 0, stop: 5, num: 3}}\n",
        "axes[0].logspace.start",
        "(0, inf]",
    ),
    ("bad_field_path", HEAD + "axes:\n  - {field: 'payload..mass', values: [1]}\n", "axes[0].field", "field path"),
    (
        "negative_samples",
        HEAD + "random: {samples: -5, fields: [{field: payload.mass_kg, uniform: [0, 1]}]}\n",
        "random.samples",
        "integer in [1, 100000], got -5",
    ),
    (
        "uniform_reversed",
        HEAD + "random: {samples: 3, fields: [{field: payload.mass_kg, uniform: [5, 1]}]}\n",
        "random.fields[0].uniform.high",
        "must be above 5",
    ),
    (
        "normal_negative_std",
        HEAD + "random: {samples: 3, fields: [{field: payload.mass_kg, normal: {mean: 1, std: -1}}]}\n",
        "random.fields[0].normal.std",
        "(0, inf]",
    ),
    (
        "log_uniform_from_zero",
        HEAD + "random: {samples: 3, fields: [{field: payload.mass_kg, log_uniform: [0, 1]}]}\n",
        "random.fields[0].log_uniform.low",
        "(0, inf]",
    ),
    (
        "two_distributions",
        HEAD + "random: {samples: 3, fields: [{field: payload.mass_kg, uniform: [0, 1], log_uniform: [1, 2]}]}\n",
        "random.fields[0].uniform",
        "exactly one of uniform, normal, log_uniform",
    ),
    (
        "unknown_method",
        HEAD + "random: {samples: 3, method: sobol, fields: [{field: payload.mass_kg, uniform: [0, 1]}]}\n",
        "random.method",
        "'random' or 'latin_hypercube'",
    ),
    ("repeats_zero", HEAD + "repeats: {count: 0, field: changes.velocity_noise.seed}\n", "repeats.count", "[1, 1"),
    (
        "field_swept_twice",
        HEAD + AXIS + "  - {field: payload.mass_kg, values: [2]}\n",
        "axes[1].field",
        "already swept by axes[0].field",
    ),
    (
        "field_set_and_swept",
        HEAD.replace("duration_s: 2", "payload.mass_kg: 1, duration_s: 2") + AXIS,
        "axes[0]",
        "set",
    ),
    ("unknown_metric", HEAD + AXIS + "metrics: [contour, speed]\n", "metrics[1]", "unknown metric 'speed'"),
    ("plot_not_kept", HEAD + AXIS + "metrics: [contour]\nplots: [estimate_M1]\n", "plots[0]", "not a kept metric"),
    ("keep_runs_text", HEAD + AXIS + "keep_runs: maybe\n", "keep_runs", "valid boolean"),
    (
        "too_many_points",
        HEAD + "random: {samples: 100000, fields: [{field: payload.offset_m.0, uniform: [0, 0.1]}]}\n" + AXIS,
        "axes",
        "200000 points; at most 100000",
    ),
    # Each point is checked as gantry-twin run would check it, and the message names the point.
    ("unknown_field_path", HEAD + "axes:\n  - {field: payload.mas_kg, values: [1]}\n", "point 0", "unknown key"),
    (
        "value_the_schema_rejects",
        HEAD + "axes:\n  - {field: payload.mass_kg, values: [0, 5, 25]}\n",
        "point 2 (payload.mass_kg=25): payload.mass_kg",
        "must be in [0, 20] kg, got 25.0",
    ),
    (
        "unknown_controller",
        HEAD + "axes:\n  - {field: controller.name, values: [diarc, fastest]}\n",
        "point 1 (controller.name=fastest): controller",
        "unknown controller 'fastest'",
    ),
    (
        "index_out_of_range",
        HEAD.replace("duration_s: 2", "disturbance.y: [{type: step, value_v: 0.5}], duration_s: 2")
        + "axes:\n  - {field: disturbance.y.3.value_v, values: [1]}\n",
        "point 0 (disturbance.y.3.value_v=1): --set disturbance.y.3",
        "index '3'",
    ),
    (
        "window_beyond_a_point",
        "scenario: no_load_circle\nset: {window_s: [0.5, 2], estimates_window_s: [1, 2]}\n"
        "axes:\n  - {field: duration_s, values: [2, 1]}\n",
        "point 1 (duration_s=1): window_s",
        "inside [0, duration_s = 1] s",
    ),
    ("set_rejected", HEAD.replace("duration_s: 2", "duration_s: -2") + AXIS, "point 0", "duration_s"),
    (
        "contour_off_the_travel",
        HEAD + "axes:\n  - {field: contour.radius_m, values: [0.2, 0.4]}\n",
        "point 1",
        "travel",
    ),
    ("duplicate_points", HEAD + "axes:\n  - {field: payload.mass_kg, values: [1, 1.0]}\n", "point 1", "as point 0"),
]


def one_line(err: str) -> str:
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize(("text", "field", "allowed"), [m[1:] for m in MALFORMED], ids=[m[0] for m in MALFORMED])
def test_malformed_sweep_exit_2_one_line_nothing_written(tmp_path, capsys, text, field, allowed):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    out = tmp_path / "out"
    code, stdout, err = run_main(["sweep", str(path), "--out", str(out), "--workers", "1"], capsys)
    assert code == 2, err
    line = one_line(err)
    assert line.startswith(f"gantry-twin: error: {path}: "), line
    assert field in line and allowed in line, (field, allowed, line)
    assert not out.exists() and stdout == ""


def test_at_least_15_malformed_sweep_files_each_with_its_own_message(tmp_path, capsys):
    messages = {}
    for name, text, _, _ in MALFORMED:
        path = tmp_path / f"{name}.yaml"
        path.write_text(text)
        code, _, err = run_main(["sweep", str(path), "--out", str(tmp_path / "out")], capsys)
        assert code == 2, name
        messages[name] = one_line(err).replace(str(path), "<file>")
    assert len(set(messages.values())) == len(messages) >= 15


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        (["--workers", "0"], "--workers: must be 1 to "),
        (["--workers", "99999999999999999999"], "(this machine's cores), got 99999999999999999999"),
        (["--workers", "100000"], "(this machine's cores), got 100000"),
        (["--scheduler", "notaurl"], "--scheduler 'notaurl': not an address; give [tcp://]HOST:PORT"),
        (["--resume", "--fresh"], "not allowed with argument"),
        (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "not allowed with argument"),
        (["--scheduler", "tcp://127.0.0.1:1"], "--scheduler tcp://127.0.0.1:1: cannot connect"),
    ],
)
def test_bad_sweep_command_lines_exit_2(tmp_path, capsys, monkeypatch, argv, fragment):
    from gantry_twin.sweep import engine

    monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 1.0)
    path = tmp_path / "ok.yaml"
    path.write_text(HEAD + AXIS)
    out = tmp_path / "out"
    code, _, err = run_main(["sweep", str(path), "--out", str(out), *argv], capsys)
    assert code == 2
    assert fragment in one_line(err)
    assert not out.exists()


def test_an_earlier_sweep_is_not_overwritten_without_resume(tmp_path, capsys):
    path = tmp_path / "ok.yaml"
    path.write_text(HEAD + AXIS)
    out = tmp_path / "out"
    out.mkdir()
    (out / "results.parquet").write_bytes(b"earlier")
    code, _, err = run_main(["sweep", str(path), "--out", str(out)], capsys)
    assert code == 2 and "--resume" in one_line(err) and "--fresh" in one_line(err)
    assert (out / "results.parquet").read_bytes() == b"earlier"


def _results_of(plan, out) -> None:
    from gantry_twin.sweep.table import ResultsTable

    table = ResultsTable(plan, out / "results.parquet")
    table.add(plan.points[0], {"contour_rms_um": 1.0, "status": "ok", "error": None, "wall_time_s": 0.5})


def test_resume_of_another_sweeps_results_is_refused_and_changes_nothing(tmp_path, capsys):
    """Sweep A's results in DIR; ``sweep B --resume`` there: exit 2, A's files as they were, what to do instead."""
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    a.write_text(HEAD + AXIS)
    b.write_text(HEAD + AXIS.replace("[0, 1]", "[0, 2]"))
    out = tmp_path / "out"
    _results_of(plan_sweep(load_sweep(a), str(a)), out)
    (out / "contour_rms_um_vs_payload.mass_kg.png").write_bytes(b"A's figure")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    code, stdout, err = run_main(["sweep", str(b), "--out", str(out), "--resume", "--workers", "1"], capsys)
    assert code == 2 and stdout == ""
    line = one_line(err)
    assert "holds the results of another sweep (plan " in line and "b.yaml is plan" in line
    assert line.endswith("nothing resumed; choose a new --out, or add --fresh to replace them")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_results_without_a_plan_key_are_not_resumed(tmp_path, capsys):
    import pyarrow as pa
    import pyarrow.parquet as pq

    a = tmp_path / "a.yaml"
    a.write_text(HEAD + AXIS)
    out = tmp_path / "out"
    out.mkdir()
    pq.write_table(pa.table({"key": ["x"], "status": ["ok"]}), out / "results.parquet")
    code, _, err = run_main(["sweep", str(a), "--out", str(out), "--resume", "--workers", "1"], capsys)
    assert code == 2 and "holds the results of another sweep (no plan key; a.yaml is plan" in one_line(err)


def test_fresh_moves_the_earlier_sweep_aside_and_says_so(tmp_path):
    from gantry_twin.sweep import set_aside
    from gantry_twin.sweep.table import plan_key

    a = tmp_path / "a.yaml"
    a.write_text(HEAD + AXIS)
    out = tmp_path / "out"
    plan = plan_sweep(load_sweep(a), str(a))
    _results_of(plan, out)
    (out / "summary.md").write_text("A\n")
    (out / "x_vs_y.png").write_bytes(b"A's figure")
    (out / "notes.txt").write_text("mine\n")
    line = set_aside(out)
    (aside,) = out.glob("replaced-*")
    assert line == (
        f"--fresh: the earlier sweep's files in {out} (sweep a.yaml, plan {plan_key(plan)}): results.parquet, "
        f"summary.md and 1 figures moved to {aside}"
    )
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", aside.name]
    assert sorted(p.name for p in aside.iterdir()) == ["results.parquet", "summary.md", "x_vs_y.png"]
    assert set_aside(out) == ""  # nothing left to move


def test_a_sweep_whose_every_point_failed_exits_1(tmp_path, capsys, monkeypatch):
    import gantry_twin.sweep as sweep
    from gantry_twin.sweep.driver import SweepOutcome

    a = tmp_path / "a.yaml"
    a.write_text(HEAD + AXIS)
    results = tmp_path / "out" / "results.parquet"
    for failures, code in ((2, 1), (1, 0)):
        outcome = SweepOutcome(2, 0, 2, failures, 1.0, 0.5, 0.5, results)
        monkeypatch.setattr(sweep, "run_sweep", lambda *args, outcome=outcome: outcome)
        got, _, err = run_main(["sweep", str(a), "--out", str(tmp_path / "out"), "--workers", "1"], capsys)
        assert got == code
        if code:
            assert one_line(err) == (
                f"gantry-twin: sweep failed: every point run failed (see the error column of {results})"
            )


def test_minimal_sweep_plans_the_grid_in_order(tmp_path):
    path = tmp_path / "minimal.yaml"
    path.write_text(MINIMAL)
    plan = plan_sweep(load_sweep(path), str(path))
    assert plan.fields == ("payload.mass_kg", "controller.name")
    assert [tuple(p.values.values()) for p in plan.points] == [(m, c) for m in (0, 2.5, 5) for c in ("diarc", "darc")]
    for point in plan.points:
        r = point.resolved
        assert r["payload"]["mass_kg"] == point.values["payload.mass_kg"]
        assert r["controller"]["name"] == point.values["controller.name"]
        assert r["duration_s"] == 2.0 and r["window_s"] == [0.5, 2.0] and r["name"] == "no_load_circle"
    assert len({p.key for p in plan.points}) == 6


def test_key_is_a_hash_of_the_resolved_scenario_and_the_version(tmp_path):
    path = tmp_path / "minimal.yaml"
    path.write_text(MINIMAL)
    plan = plan_sweep(load_sweep(path), str(path))
    resolved = plan.points[0].resolved
    assert point_key(resolved, plan.version) == plan.points[0].key
    assert point_key(resolved, plan.version + "+1") != plan.points[0].key
    changed = {**resolved, "duration_s": 2.0000001}
    assert point_key(changed, plan.version) != plan.points[0].key


@pytest.mark.parametrize("value", [1e-05, 0.1, 2.5, 1 / 3, 5, "5", "diarc", True, None, [0.5, 2.0], 1e300])
def test_override_text_reads_back_as_the_same_value(value):
    key, _, text = override("a.b", value).partition("=")
    assert key == "a.b"
    back = yaml.safe_load(text)
    assert back == value and type(back) is type(value)


def test_every_shipped_sweep_plans(capsys):
    shipped = sorted(sweeps_dir().glob("*.yaml"))
    assert {p.stem for p in shipped} >= {"payload_0_20kg", "friction_montecarlo", "feedrate"}
    sizes = {}
    for path in shipped:
        plan = plan_sweep(load_sweep(path), str(path))
        sizes[path.stem] = len(plan.points)
    assert sizes["friction_montecarlo"] == 100
    assert sizes["payload_0_20kg"] == 22
    feed = plan_sweep(load_sweep(sweeps_dir() / "feedrate.yaml"), "feedrate.yaml")
    speeds = [0.2 * p.values["contour.timing.rate_rad_s"] for p in feed.points]  # m/s on the 0.2 m circle
    assert speeds[0] == pytest.approx(0.05) and speeds[-1] == pytest.approx(0.6)


# ---------------------------------------------------------------------------
# Sampling.


def test_latin_hypercube_puts_one_sample_in_each_stratum_of_each_field():
    n, d = 50, 3
    u = unit_samples(n, d, "latin_hypercube", seed=7)
    for j in range(d):
        assert sorted(np.floor(u[:, j] * n).astype(int)) == list(range(n))
    plain = unit_samples(n, d, "random", seed=7)
    assert any(len(set(np.floor(plain[:, j] * n).astype(int))) < n for j in range(d))


def test_draws_are_seeded_and_follow_their_distributions():
    text = HEAD + (
        "random:\n  samples: 4000\n  seed: 3\n  fields:\n"
        "    - {field: a, uniform: [2, 4]}\n"
        "    - {field: b, normal: {mean: 1, std: 0.5}}\n"
        "    - {field: c, log_uniform: [0.001, 1]}\n"
        "    - {field: d, normal: {mean: 0, std: 1, min: -0.5, max: 2}}\n"
    )
    spec = parse_sweep(text, "s.yaml").random
    first, again = draws(spec), draws(spec)
    assert first == again
    a, b, c, d = (np.array([x[k] for x in first]) for k in "abcd")
    assert a.min() >= 2 and a.max() < 4 and abs(a.mean() - 3) < 0.05
    assert abs(b.mean() - 1) < 0.05 and abs(b.std() - 0.5) < 0.03
    logc = np.log10(c)
    assert logc.min() >= -3 and logc.max() < 0 and abs(logc.mean() + 1.5) < 0.05
    assert d.min() >= -0.5 and d.max() <= 2 and (d < 0).any()
    other = draws(spec.model_copy(update={"seed": 4}))
    assert other != first


def test_inverse_cdfs_against_scipy():
    from scipy import stats

    u = np.linspace(0.01, 0.99, 9)
    assert np.allclose(Uniform(low=-1, high=3).ppf(u), stats.uniform(-1, 4).ppf(u))
    assert np.allclose(LogUniform(low=0.01, high=10).ppf(u), stats.loguniform(0.01, 10).ppf(u))
    truncated = stats.truncnorm((0.5 - 1) / 2, (4 - 1) / 2, loc=1, scale=2)
    assert np.allclose(Normal(mean=1, std=2, min=0.5, max=4).ppf(u), truncated.ppf(u))
    assert math.isfinite(Normal(mean=0, std=1).ppf(np.array([0.0]))[0])


def test_random_and_grid_and_repeats_combine(tmp_path):
    text = HEAD + (
        "axes:\n  - {field: controller.name, values: [diarc, darc]}\n"
        "random: {samples: 3, seed: 1, method: latin_hypercube, fields: [{field: payload.mass_kg, uniform: [0, 5]}]}\n"
        "repeats: {count: 2, seed: 10, field: changes.velocity_noise.seed}\n"
        "set: {duration_s: 2, window_s: [0.5, 2], estimates_window_s: [1, 2],\n"
        "      changes.velocity_noise.std_m_s: [0.001, 0]}\n"
    )
    path = tmp_path / "mc.yaml"
    path.write_text(text.replace(HEAD, "scenario: no_load_circle\n"))
    plan = plan_sweep(load_sweep(path), str(path))
    assert len(plan.points) == 2 * 3 * 2
    assert [(p.sample, p.seed) for p in plan.points[:4]] == [(0, 10), (0, 11), (1, 10), (1, 11)]
    assert all(p.resolved["changes"]["velocity_noise"]["seed"] == p.seed for p in plan.points)
    masses = {p.values["payload.mass_kg"] for p in plan.points}
    assert len(masses) == 3 and all(0 <= m < 5 for m in masses)


def test_plan_errors_are_scenario_errors_naming_the_sweep_file(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(HEAD + "axes:\n  - {field: payload.mass_kg, values: [30]}\n")
    with pytest.raises(ScenarioError) as caught:
        plan_sweep(load_sweep(path), str(path))
    assert caught.value.source == str(path) and caught.value.field.startswith("point 0 (payload.mass_kg=30)")


def test_sweep_takes_the_progress_flags(monkeypatch):
    from gantry_twin.cli import app as cli

    parser = cli.build_parser()
    assert parser.parse_args(["sweep", "s.yaml", "--no-progress"]).progress is False
    assert parser.parse_args(["sweep", "s.yaml", "--progress"]).progress is True
    args = parser.parse_args(["sweep", "s.yaml"])
    monkeypatch.setattr(cli.sys.stderr, "isatty", lambda: False)
    assert args.progress is None and cli.progress_wanted(args) is False


def test_tick_labels_of_swept_objects_name_only_the_leaves_that_differ():
    from gantry_twin.sweep.plots import tick_labels

    contours = [
        json.dumps({"type": "circle", "radius_m": r, "centre_m": [0.0, 0.0], "timing": {"rate_rad_s": w}})
        for r, w in [(0.02, 1.0), (0.02, 2.5), (0.2, 1.0)]
    ] + [json.dumps({"type": "ellipse", "semi_x_m": 0.2, "centre_m": [0.0, 0.0], "timing": {"rate_rad_s": 1.0}})]
    labels = tick_labels(contours)
    assert labels[0] == "type=circle radius_m=0.02 rate_rad_s=1.0"
    assert labels[3] == "type=ellipse rate_rad_s=1.0 semi_x_m=0.2"  # centre_m is the same everywhere: left out
    assert len(set(labels)) == 4
    assert tick_labels([0.123456, 2]) == ["0.1235", "2"]
    assert tick_labels(["a", "{not json"]) == ["a", "{not json"]
