"""The command line through main(): bad input, run outputs, determinism, atomic writes, report."""

from __future__ import annotations

import json
import math

import numpy as np
import pyarrow.parquet as pq
import pytest

from gantry_twin.cli import app as cli
from gantry_twin.outputs import files as results
from gantry_twin.plant.model import THETA_NAMES, Payload, Plant
from gantry_twin.run import execute
from gantry_twin.scenario import shipped

from .helpers import FLOAT32_REL, deviation_pct, read_rrd, run_main, scalars, spec_theta, trace_column

#: Short runs: 0.2 s of simulation (1000 samples) with windows inside it.
OVERRIDES_SHORT = ["duration_s=0.2", "window_s=[0.05, 0.2]", "estimates_window_s=[0.1, 0.2]"]
SHORT = [word for override in OVERRIDES_SHORT for word in ("--set", override)]

SUMMARY_KEYS = {
    "schema_version",
    "scenario",
    "plant",
    "controller",
    "overrides",
    "controller_option",
    "duration_s",
    "sample_period_s",
    "steps",
    "status",
    "contour_error_um",
    "whole_run",
    "contour_error_per_period_um",
    "estimates_window_s",
    "estimates",
    "confidence",
    "events",
    "end_stop_contacts",
    "saturation",
}

# (id, file text, field named in the message, what is allowed)
MALFORMED = [
    ("yaml_syntax", "payload: {mass_kg: 5\n", "line 2", "YAML syntax error"),
    ("yaml_tab", "payload:\n\tmass_kg: 5\n", "line 2", "YAML syntax error"),
    ("yaml_duplicate_key", "duration_s: 1\nduration_s: 2\n", "duplicate key 'duration_s'", "line 2"),
    ("empty", "", "empty file", "YAML mapping"),
    ("only_comment", "# nothing\n", "empty file", "YAML mapping"),
    ("top_level_list", "- 1\n- 2\n", "top level", "mapping of fields"),
    ("top_level_scalar", "circle\n", "top level", "mapping of fields"),
    ("unknown_top_key", "durations: 3\n", "durations", "allowed: name, description, contour"),
    ("unknown_nested_key", "payload: {mass: 5}\n", "payload.mass", "allowed: mass_kg, offset_m"),
    ("plant_file_missing", "plant: {file: no_such_model.xml}\n", "plant.file", "no such file"),
    ("mass_wrong_type", "payload: {mass_kg: heavy}\n", "payload.mass_kg", "valid number"),
    ("mass_negative", "payload: {mass_kg: -1}\n", "payload.mass_kg", "[0, 20] kg"),
    ("mass_absurd", "payload: {mass_kg: 5000}\n", "payload.mass_kg", "[0, 20] kg"),
    ("mass_nan", "payload: {mass_kg: .nan}\n", "payload.mass_kg", "[0, 20] kg"),
    ("mass_bool", "payload: {mass_kg: true}\n", "payload.mass_kg", "number, not a boolean"),
    ("offset_out_of_plate", "payload: {offset_m: [0, 0, 1.0]}\n", "payload.offset_m[2]", "[-0.2, 0.2] m"),
    ("window_outside_duration", "window_s: [5, 40]\n", "window_s", "inside [0, duration_s = 30] s"),
    ("window_reversed", "window_s: [4, 2]\n", "window_s", "end must be after start"),
    ("window_past_a_short_run", "duration_s: 1\nwindow_s: [0.5, 2]\n", "window_s", "inside [0, duration_s = 1] s"),
    ("estimates_window_outside", "estimates_window_s: [29, 31]\n", "estimates_window_s", "inside [0, duration_s"),
    ("window_between_samples", "window_s: [0.10001, 0.10011]\n", "window_s", "holds no sample"),
    (
        "duration_below_two_samples",
        "duration_s: 0.0003\nwindow_s: [0, 0.0003]\nestimates_window_s: [0, 0.0003]\n",
        "duration_s",
        "at least two samples",
    ),
    ("duration_negative", "duration_s: -3\n", "duration_s", "(0, 3600] s"),
    ("duration_string", "duration_s: long\n", "duration_s", "valid number"),
    ("disturbance_unknown_axis", "disturbance: {z: []}\n", "disturbance.z", "allowed: x, y"),
    (
        "disturbance_unknown_type",
        "disturbance: {y: [{type: pulse, value_v: 1}]}\n",
        "disturbance.y[0].type",
        "allowed: 'step', 'ramp', 'sine'",
    ),
    ("disturbance_missing_type", "disturbance: {y: [{value_v: 1}]}\n", "disturbance.y[0].type", "step, ramp, sine"),
    (
        "disturbance_end_before_start",
        "disturbance: {y: [{type: step, value_v: 1, start_s: 3, end_s: 2}]}\n",
        "disturbance.y[0]",
        "end_s must be after start_s",
    ),
    (
        "disturbance_absurd_volts",
        "disturbance: {x: [{type: step, value_v: 50}]}\n",
        "disturbance.x[0].value_v",
        "[-10, 10] V",
    ),
    ("disturbance_not_list", "disturbance: {y: {type: step, value_v: 1}}\n", "disturbance.y", "valid list"),
    ("ramp_missing_end", "disturbance: {y: [{type: ramp, to_v: 1}]}\n", "disturbance.y[0].end_s", "required"),
    ("unknown_controller", "controller: {name: lqr}\n", "controller", "available: darc, diarc, drc, fmu, pd"),
    ("controller_not_mapping", "controller: diarc\n", "controller", "valid dictionary"),
    (
        "unknown_controller_option",
        "controller: {name: diarc, options: {gain: 3}}\n",
        "controller.options.gain",
        "allowed: gains, estimator",
    ),
    (
        "bad_estimator_name",
        "controller: {name: diarc, options: {estimator: fast}}\n",
        "controller.options.estimator",
        "'paper' or 'recommended'",
    ),
    (
        "bad_estimator_filter",
        "controller: {name: diarc, options: {estimator: {filter_hz: [0, 50]}}}\n",
        "controller.options.estimator.filter_hz[0]",
        "[5, 500] Hz",
    ),
    (
        "darc_gamma_short",
        "controller: {name: darc, options: {gamma: [1, 2]}}\n",
        "controller.options.gamma",
        "too few items",
    ),
    (
        "theta0_outside_bounds",
        "controller: {name: drc, options: {gains: {theta0: [0.3, 0.55, 0.35, 0.5, 0.1, 0.15, 0, 0]}}}\n",
        "controller.options.gains",
        "theta_min <= theta0 <= theta_max",
    ),
    ("unknown_contour_type", "contour: {type: square}\n", "contour.type", "allowed: 'circle', 'ellipse'"),
    ("contour_outside_travel", "contour: {type: circle, radius_m: 0.3}\n", "contour", "the travel allows"),
    ("ellipse_off_centre", "contour: {type: ellipse, centre_m: [0.2, 0]}\n", "contour", "the travel allows"),
    ("timing_start", "contour: {timing: {start: later}}\n", "contour.timing.start", "'on_path' or 'rest'"),
    ("timing_rate_negative", "contour: {timing: {rate_rad_s: -2}}\n", "contour.timing.rate_rad_s", "(0, 20] rad/s"),
    ("centre_three_numbers", "contour: {centre_m: [0, 0, 0]}\n", "contour.centre_m", "at most 2 items"),
    ("sensing_bool", "sensing: {quantize: maybe}\n", "sensing.quantize", "valid boolean"),
    ("sensing_resolution", "sensing: {resolution_m: 0.5}\n", "sensing.resolution_m", "[1e-09, 0.001] m"),
    ("trace_stride_zero", "outputs: {trace_stride: 0}\n", "outputs.trace_stride", "greater than or equal to 1"),
    ("name_not_text", "name: [1, 2]\n", "name", "valid string"),
    ("description_not_text", "description: {a: 1}\n", "description", "valid string"),
    ("monitor_enable_not_bool", "monitor: {enable: maybe}\n", "monitor.enable", "valid boolean"),
    ("friction_model_unknown", "plant: {friction: {model: stribeck}}\n", "plant.friction.model", "'coulomb'"),
    (
        "lugre_too_stiff",
        "plant: {friction: {model: lugre, x: {sigma0_n_m: 1.0e9}}}\n",
        "plant.friction.x.sigma0_n_m",
        "pre-sliding distance",
    ),
    ("unknown_change", "changes: {bogus: 1}\n", "changes.bogus", "allowed: friction_drift, payload_change"),
    (
        "payload_change_before_start",
        "changes: {payload_change: [{time_s: -1, mass_kg: 5}]}\n",
        "changes.payload_change[0].time_s",
        "got -1",
    ),
]


def assert_one_line_error(err: str, *fragments: str) -> None:
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


@pytest.mark.parametrize(("text", "field", "allowed"), [m[1:] for m in MALFORMED], ids=[m[0] for m in MALFORMED])
def test_malformed_scenario_exit_2_one_line_nothing_written(tmp_path, capsys, text, field, allowed):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    out = tmp_path / "out"
    code, stdout, err = run_main(["run", str(path), "--out", str(out)], capsys)
    assert code == 2
    assert_one_line_error(err, str(path), field, allowed)
    assert not out.exists()
    assert stdout == ""


#: Cases that are the same malformation written differently, so get the same message: case -> its twin.
SAME_MALFORMATION = {"only_comment": "empty"}


def test_at_least_25_malformed_files(tmp_path, capsys):
    """The program tells every malformation here apart (a message of its own once the file's name is taken
    out: at least 25 of them), and every top-level field it accepts (the list its own error gives) has a case."""
    messages: dict[str, str] = {}
    for name, text, _, _ in MALFORMED:
        path = tmp_path / f"{name}.yaml"
        path.write_text(text)
        code, _, err = run_main(["validate", str(path)], capsys)
        assert code == 2, name
        messages[name] = err.strip().replace(str(path), "<file>")
    for name, twin in SAME_MALFORMATION.items():
        assert messages.pop(name) == messages[twin]
    shared = {m: [n for n in messages if messages[n] == m] for m in messages.values()}
    assert len(shared) == len(messages), [names for names in shared.values() if len(names) > 1]
    assert len(shared) >= 25
    unknown = tmp_path / "unknown.yaml"
    unknown.write_text("no_such_field: 1\n")
    _, _, err = run_main(["validate", str(unknown)], capsys)
    accepted = err.strip().split("allowed: ", 1)[1].split(", ")
    assert len(accepted) >= 10 and "duration_s" in accepted
    malformed_fields = {field.split(".")[0].split("[")[0] for _, _, field, _ in MALFORMED}
    assert not set(accepted) - malformed_fields, f"fields without a malformed case: {set(accepted) - malformed_fields}"


@pytest.mark.parametrize(
    ("text", "field", "allowed"), [m[1:] for m in MALFORMED[::5]], ids=[m[0] for m in MALFORMED[::5]]
)
def test_validate_rejects_the_same_files(tmp_path, capsys, text, field, allowed):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    code, _, err = run_main(["validate", str(path)], capsys)
    assert code == 2
    assert_one_line_error(err, str(path), field, allowed)


@pytest.mark.parametrize(
    ("argv", "fragments"),
    [
        (["run", "{tmp}/missing.yaml"], ["missing.yaml", "no such file"]),
        (["run", "{tmp}"], ["is a directory"]),
        (["run", "{shipped}", "--set", "payload.mass_kg"], ["--set", "expected key.path=value"]),
        (["run", "{shipped}", "--set", "payload.mass_kg=[5"], ["--set payload.mass_kg", "not valid YAML"]),
        (["run", "{shipped}", "--set", "payload.mass_kg=-2"], ["payload.mass_kg", "[0, 20] kg"]),
        (["run", "{shipped}", "--set", "payload.mass_kg.x=1"], ["payload.mass_kg", "not a mapping"]),
        (["run", "{shipped}", "--controller", "nope"], ["unknown controller 'nope'", "available:"]),
        (["run", "{shipped}", "--bogus"], ["unrecognized arguments: --bogus"]),
        (["report", "--workers", "0", "--out", "{tmp}/r"], ["--workers", "positive integer"]),
        (["report", "--set", "duration_s=-1", "--out", "{tmp}/r"], ["duration_s", "(0, 3600] s"]),
        (["frobnicate"], ["invalid choice"]),
    ],
)
def test_bad_command_lines_exit_2_with_one_line(tmp_path, capsys, argv, fragments):
    argv = [a.format(tmp=tmp_path, shipped=shipped("no_load_circle")) for a in argv]
    code, _, err = run_main(argv, capsys)
    assert code == 2
    assert_one_line_error(err, *fragments)
    assert not (tmp_path / "r").exists()


def test_validate_accepts_every_shipped_scenario(capsys):
    from gantry_twin.scenario import shipped_scenarios

    paths = [str(p) for p in shipped_scenarios()]
    code, out, err = run_main(["validate", *paths], capsys)
    assert code == 0, err
    assert out.count(": ok") == len(paths)


def _window_rms_max_um(table, window):
    t = table.column("t_s").to_numpy()
    eps = np.abs(trace_column(table, "eps_c_m")[(t >= window[0]) & (t < window[1])]) * 1e6
    return math.sqrt(float(np.mean(eps**2))), float(eps.max())


def test_run_writes_scenario_summary_trace(tmp_path, capsys):
    out = tmp_path / "out"
    code, stdout, err = run_main(["run", str(shipped("load_5kg_ellipse")), *SHORT, "--out", str(out)], capsys)
    assert code == 0, err
    assert "rms" in stdout and "M1" in stdout
    assert sorted(p.name for p in out.iterdir()) == [
        "plots",
        "run_info.json",
        "scenario.yaml",
        "summary.json",
        "trace.parquet",
    ]
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary) == SUMMARY_KEYS
    assert summary["scenario"] == "load_5kg_ellipse" and summary["controller"] == "diarc"
    assert summary["steps"] == 1000 and summary["contour_error_um"]["window_s"] == [0.05, 0.2]
    assert set(summary["estimates"]) == {"M1", "M2", "B1", "B2", "Af1", "Af2", "dN1", "dN2"}
    assert summary["plant"] == "rig plant (models/rig.xml)"  # the default machine
    dn1 = summary["estimates"]["dN1"]
    assert dn1["true"] == pytest.approx(0.0515, abs=1e-12)  # the rig's offset (models/rig.xml)
    assert dn1["error_pct"] == pytest.approx(100 * (dn1["estimate"] / dn1["true"] - 1))
    assert json.loads((out / "run_info.json").read_text())["wall_time_s"] > 0

    table = pq.read_table(out / "trace.parquet")
    assert table.num_rows == 1000
    for column in (
        "t_s",
        "x_m",
        "y_m",
        "x_d_m",
        "y_d_m",
        "eps_c_m",
        "u_x_v",
        "u_y_v",
        "d_y_v",
        "theta_hat_M1",
        "theta_hat_dN2",
        "dc_hat_x",
    ):
        assert column in table.column_names
    rms, peak = _window_rms_max_um(table, (0.05, 0.2))
    assert summary["contour_error_um"]["rms"] == pytest.approx(rms, rel=2 * FLOAT32_REL)
    assert summary["contour_error_um"]["max"] == pytest.approx(peak, rel=2 * FLOAT32_REL)
    # Estimates: the trace's mean over estimates_window_s, judged against the default machine (the rig plant)
    # with 5 kg on the X carriage: M1 = (8.28 + 5) / 69, M2 = (34.5 + 5) / 69 (tests/helpers.py); B, Af, dN the
    # rig's true values (checked against an independent fit in tests/test_rig_plant.py).
    est_t = table.column("t_s").to_numpy()
    sel = (est_t >= 0.1) & (est_t < 0.2)
    rig_theta = Plant.shipped("rig", Payload(mass_kg=5.0)).true_parameters()
    for name, true in zip(THETA_NAMES[:6], [*spec_theta(5.0)[:2], *rig_theta[2:6]], strict=True):
        reported = summary["estimates"][name]
        estimate = trace_column(table, f"theta_hat_{name}")[sel].mean()
        assert reported["true"] == pytest.approx(true, rel=1e-12), name
        assert reported["estimate"] == pytest.approx(estimate, rel=2 * FLOAT32_REL), name
        pct_tolerance = 100 * 2 * FLOAT32_REL * abs(estimate / true)  # the estimate's float32 rounding, in %
        assert reported["error_pct"] == pytest.approx(deviation_pct(estimate, true), abs=pct_tolerance), name
    # The resolved scenario is complete and runs again to the same summary.
    resolved = (out / "scenario.yaml").read_text()
    assert "duration_s: 0.2" in resolved and "mass_kg: 5.0" in resolved
    again = tmp_path / "again"
    code, _, err = run_main(["run", str(out / "scenario.yaml"), "--out", str(again)], capsys)
    assert code == 0, err
    first = json.loads((out / "summary.json").read_text())
    second = json.loads((again / "summary.json").read_text())
    made = ("scenario", "overrides", "controller_option")  # how each was made differs, not what it holds
    assert {k: v for k, v in first.items() if k not in made} == {k: v for k, v in second.items() if k not in made}
    assert first["overrides"] == OVERRIDES_SHORT and second["overrides"] == []


def test_same_scenario_twice_gives_byte_identical_summaries(tmp_path, capsys):
    args = ["run", str(shipped("step_disturbance_circle")), *SHORT, "--set", "disturbance.y.0.start_s=0.1"]
    assert run_main([*args, "--out", str(tmp_path / "a")], capsys)[0] == 0
    assert run_main([*args, "--out", str(tmp_path / "b"), "--progress"], capsys)[0] == 0
    a, b = (tmp_path / "a" / "summary.json").read_bytes(), (tmp_path / "b" / "summary.json").read_bytes()
    assert a == b
    assert (tmp_path / "a" / "scenario.yaml").read_bytes() == (tmp_path / "b" / "scenario.yaml").read_bytes()


def test_default_scenario_and_default_out_dir(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = run_main(["run", *SHORT, "--controller", "drc", "--set", "outputs.trace=false"], capsys)
    assert code == 0, err
    out = tmp_path / "runs" / "no_load_circle" / "latest"  # the new run directory under runs/<name>/
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scenario"] == "no_load_circle" and summary["controller"] == "drc"
    assert summary["controller_option"] == "drc" and summary["overrides"] == [*OVERRIDES_SHORT, "outputs.trace=false"]
    assert "estimates" not in summary  # DRC estimates nothing
    assert not (out / "trace.parquet").exists()
    assert not (out / "plots").exists()  # nothing to draw from
    assert "no plots: no trace.parquet" in err


def test_shipped_scenarios_can_be_named_without_a_path(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = run_main(["validate", "load_5kg_circle", "step_disturbance_ellipse"], capsys)
    assert code == 0, err
    assert str(shipped("load_5kg_circle")) in out
    code, _, err = run_main(["validate", "no_such_scenario"], capsys)
    assert code == 2
    assert_one_line_error(err, "no such scenario file or shipped scenario 'no_such_scenario'", "shipped: ")


def test_set_overrides_reach_the_run(tmp_path, capsys):
    out = tmp_path / "o"
    args = [
        "run",
        str(shipped("no_load_circle")),
        *SHORT,
        "--set",
        "payload.mass_kg=2.5",
        "--set",
        "outputs.trace_stride=10",
        "--out",
        str(out),
    ]
    assert run_main(args, capsys)[0] == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["estimates"]["M1"]["true"] == pytest.approx((8.28 + 2.5) / 69)
    assert pq.read_table(out / "trace.parquet").num_rows == 100


def test_atomic_write_leaves_nothing_when_the_writer_fails(tmp_path):
    target = tmp_path / "file.bin"

    def half(fh):
        fh.write(b"partial")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        results.atomic_write(target, half)
    assert list(tmp_path.iterdir()) == []
    results.atomic_write_text(target, "done")
    assert target.read_text() == "done"
    with pytest.raises(OSError):
        results.atomic_write(target, half)
    assert target.read_text() == "done"  # the old complete file survives a failed rewrite
    assert [p.name for p in tmp_path.iterdir()] == ["file.bin"]


def _files(out):
    """Every file under ``out`` but run_info.json (its times differ), by path: its bytes."""
    return {
        p.relative_to(out).as_posix(): p.read_bytes()
        for p in out.rglob("*")
        if p.is_file() and p.name != "run_info.json"
    }


def test_failure_mid_write_leaves_no_complete_looking_run(tmp_path, capsys, monkeypatch):
    from gantry_twin import run as run_module

    out = tmp_path / "out"
    args = ["run", str(shipped("no_load_circle")), *SHORT, "--out", str(out)]
    assert run_main(args, capsys)[0] == 0
    before = _files(out)
    assert "plots/eps_c.png" in before

    def broken_write_table(self, table, **kwargs):
        raise OSError("injected failure mid-write")

    # The trace fails while the run writes it: the previous complete run stays as it was.
    with monkeypatch.context() as patch:
        patch.setattr(results.pq.ParquetWriter, "write_table", broken_write_table)
        code, _, err = run_main(args, capsys)
    assert code == 1
    assert_one_line_error(err, "run failed", "injected failure mid-write")
    assert _files(out) == before

    # Writing fails after the old summary.json is gone: no summary.json, no file of this run, no temporary file.
    def broken_text(path, text):
        raise OSError("injected failure in the last writes")

    monkeypatch.setattr(run_module, "atomic_write_text", broken_text)
    code, _, err = run_main(args, capsys)
    assert code == 1
    assert_one_line_error(err, "run failed", "injected failure in the last writes")
    assert not (out / "summary.json").exists()  # the stale summary is gone: the directory is visibly incomplete
    assert not [p for p in out.iterdir() if p.name.endswith(".part")]


def test_run_failure_exit_1(tmp_path, capsys, monkeypatch):
    """An error that is not a fault of the simulated run (tests/test_run.py has those) leaves nothing."""
    from gantry_twin import run as run_module

    def fail(*args, **kwargs):
        raise RuntimeError("the simulator itself broke")

    monkeypatch.setattr(run_module, "simulate", fail)
    out = tmp_path / "o"
    code, _, err = run_main(["run", str(shipped("no_load_circle")), *SHORT, "--out", str(out)], capsys)
    assert code == 1
    assert_one_line_error(err, "run failed", "RuntimeError", "simulator itself broke")
    assert not out.exists()


def test_progress_bar_only_reads_the_trace(tmp_path, capsys):
    from gantry_twin.scenario import build, load_scenario

    overrides = ["duration_s=0.1", "window_s=[0, 0.1]", "estimates_window_s=[0, 0.1]"]
    plain = execute(build(load_scenario(shipped("no_load_circle"), overrides)))
    shown = execute(build(load_scenario(shipped("no_load_circle"), overrides)), [cli.ProgressBar(True, 0.0)])
    np.testing.assert_array_equal(plain.q_m, shown.q_m)
    assert "simulated" in capsys.readouterr().err


def test_run_records_telemetry_to_a_file(tmp_path):
    """The recording `run --save` writes holds the run's trace.parquet, sample for sample (the estimates at 1 kHz)."""
    rrd = tmp_path / "run.rrd"
    out = tmp_path / "out"
    code = cli.main(["run", "no_load_circle", *SHORT, "--out", str(out), "--save", str(rrd)])
    assert code == 0
    table = pq.read_table(out / "trace.parquet")
    assert table.num_rows == 1000
    data = read_rrd(rrd)
    times_ns = np.rint(table.column("t_s").to_numpy() * 1e9).astype(np.int64)
    # entity -> (the trace's values, relative tolerance: float32 columns are rounded, positions exact)
    recorded = {
        "errors/contour/eps_c_um": (trace_column(table, "eps_c_m") * 1e6, 2 * FLOAT32_REL),
        "errors/axial/e_x_um": (trace_column(table, "x_m") * 1e6 - trace_column(table, "x_d_m") * 1e6, 1e-12),
        "inputs/u_x_V": (trace_column(table, "u_x_v"), 2 * FLOAT32_REL),
        "inputs/u_y_V": (trace_column(table, "u_y_v"), 2 * FLOAT32_REL),
        "estimates/M1_V_s2_per_m/estimate": (trace_column(table, "theta_hat_M1")[::5], 2 * FLOAT32_REL),  # 1 kHz
        "estimates/Af2_V/estimate": (trace_column(table, "theta_hat_Af2")[::5], 2 * FLOAT32_REL),
    }
    for entity, (expected, rtol) in recorded.items():
        at = times_ns[::5] if entity.startswith("estimates/") else times_ns
        np.testing.assert_array_equal(data[entity]["time_ns"], at, err_msg=entity)
        np.testing.assert_allclose(scalars(data, entity)[:, 0], expected, rtol=rtol, atol=1e-9, err_msg=entity)
    # The 3D view: the X carriage's translation, 50 Hz (every 100th sample), float32.
    carriage = data["gantry/y_carriage/x_carriage"]
    np.testing.assert_array_equal(carriage["time_ns"], times_ns[::100])
    translation = np.asarray(carriage["Transform3D:translation"], dtype=np.float32).reshape(-1, 3)
    np.testing.assert_array_equal(translation[:, 0], table.column("x_m").to_numpy()[::100].astype(np.float32))


def test_run_viewer_without_display_is_a_one_line_error(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    code = cli.main(["run", "no_load_circle", *SHORT, "--out", str(tmp_path / "out"), "--viewer"])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "--serve-web" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_estimates_are_judged_against_the_truth_of_their_window(tmp_path, capsys):
    """A payload picked up at 0.3 s: a window before it compares with the unloaded M1, one across it with the mean."""
    scenario = tmp_path / "pickup.yaml"
    scenario.write_text(
        "contour: {type: circle, radius_m: 0.2, timing: {rate_rad_s: 2.0, start: on_path}}\n"
        "controller: {name: diarc}\n"
        "changes: {payload_change: [{time_s: 0.3, mass_kg: 5.0}]}\n"
        "duration_s: 0.5\n"
        "window_s: [0.1, 0.5]\n"
    )
    m1_free, m1_loaded = spec_theta(0.0)[0], spec_theta(5.0)[0]
    for window, fraction_loaded in (([0.1, 0.3], 0.0), ([0.2, 0.4], 0.5), ([0.3, 0.5], 1.0)):
        out = tmp_path / f"out_{window[0]}"
        args = ["run", str(scenario), "--set", f"estimates_window_s={window}", "--out", str(out)]
        code, _, err = run_main(args, capsys)
        assert code == 0, err
        m1 = json.loads((out / "summary.json").read_text())["estimates"]["M1"]
        table = pq.read_table(out / "trace.parquet")
        t = table.column("t_s").to_numpy()
        in_window = (t >= window[0]) & (t < window[1])
        true = np.where(t >= 0.3, m1_loaded, m1_free)[in_window].mean()
        assert true == pytest.approx(m1_free + fraction_loaded * (m1_loaded - m1_free), rel=1e-3)
        assert m1["true"] == pytest.approx(true, rel=1e-12)
        estimate = trace_column(table, "theta_hat_M1")[in_window].mean()
        pct_tolerance = 100 * 2 * FLOAT32_REL * abs(estimate / true)  # the estimate's float32 rounding, in %
        assert m1["error_pct"] == pytest.approx(deviation_pct(estimate, true), abs=pct_tolerance)
    true_m1 = table.column("true_theta_M1").to_numpy()
    assert np.allclose(true_m1[t < 0.3 - 1e-9], m1_free) and np.allclose(true_m1[t > 0.3 + 1e-9], m1_loaded)


def test_trace_has_no_true_theta_columns_when_the_plant_does_not_change(tmp_path, capsys):
    out = tmp_path / "o"
    assert run_main(["run", str(shipped("no_load_circle")), *SHORT, "--out", str(out)], capsys)[0] == 0
    names = pq.read_table(out / "trace.parquet").column_names
    assert "theta_hat_M1" in names and not any(n.startswith("true_theta") for n in names)


@pytest.mark.parametrize("command", [["run"], ["monitor", "no_load_circle"], ["report"]])
def test_every_long_command_takes_progress_flags(command, monkeypatch):
    parser = cli.build_parser()
    assert parser.parse_args([*command, "--no-progress"]).progress is False
    assert parser.parse_args([*command, "--progress"]).progress is True
    args = parser.parse_args(command)
    monkeypatch.setattr(cli.sys.stderr, "isatty", lambda: False)
    assert args.progress is None and cli.progress_wanted(args) is False


def test_version_everywhere(capsys):
    """`gantry-twin --version`, `python -m gantry_twin --version` and gantry_twin.__version__ agree."""
    import subprocess
    import sys

    import gantry_twin
    from gantry_twin.run import package_version

    assert gantry_twin.__version__ == package_version()
    with pytest.raises(SystemExit) as stopped:
        cli.build_parser().parse_args(["--version"])
    assert stopped.value.code == 0
    assert capsys.readouterr().out.strip() == f"gantry-twin {package_version()}"
    child = subprocess.run([sys.executable, "-m", "gantry_twin", "--version"], capture_output=True, text=True)
    assert child.returncode == 0 and child.stdout.strip() == f"gantry-twin {package_version()}", child.stderr


def test_run_scenario_from_python_is_the_command_s_run(tmp_path):
    """gantry_twin.run_scenario gives the summary `gantry-twin run` writes for the same scenario and --set."""
    import gantry_twin
    from gantry_twin.outputs.summary import RunSummary

    overrides = ["duration_s=0.6", "window_s=[0.1, 0.6]", "estimates_window_s=[0.1, 0.6]"]
    result = gantry_twin.run_scenario("no_load_circle", overrides, "darc", out=tmp_path / "py")
    assert result.trace.filled == 3000
    code = cli.main(
        ["run", "no_load_circle", "--controller", "darc", "--no-plots", "--out", str(tmp_path / "cli")]
        + [a for o in overrides for a in ("--set", o)]
    )
    assert code == 0
    from_cli = RunSummary.read(tmp_path / "cli" / "summary.json")
    assert from_cli.contour_error_um == result.summary.contour_error_um
    assert RunSummary.read(tmp_path / "py" / "summary.json").contour_error_um == result.summary.contour_error_um


def test_a_monitor_that_judged_nothing_says_so_and_exits_5(tmp_path, capsys):
    """A run whose every parameter stays in the baseline window is not a healthy verdict: exit 5, stderr, and
    summary.json's health.judged is empty."""
    code = cli.main(
        [
            "monitor",
            "no_load_circle",
            "--set",
            "duration_s=1",
            "--no-plots",
            "--out",
            str(tmp_path / "m"),
            "--set",
            "monitor.baseline_window_s=[0.2, 1]",
        ]
    )
    assert code == cli.EXIT_NOT_JUDGED == 5
    assert "monitor judged nothing" in capsys.readouterr().err
    assert json.loads((tmp_path / "m" / "summary.json").read_text())["health"]["judged"] == []


def test_a_crash_in_compiled_code_prints_the_python_stacks(tmp_path):
    """The command line turns on faulthandler: a segmentation fault after main() started (as numba's or MuJoCo's
    compiled code could cause) names where Python was, instead of ending with a bare signal."""
    import subprocess
    import sys

    code = (
        "import ctypes, sys\n"
        "from gantry_twin.cli.app import main\n"
        "sys.argv = ['gantry-twin', 'scenarios']\n"
        "main()\n"
        "ctypes.string_at(0)\n"
    )
    child = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120, check=False
    )
    assert child.returncode < 0, (child.returncode, child.stderr)
    assert "Fatal Python error: Segmentation fault" in child.stderr and "string_at" in child.stderr, child.stderr
