"""Hostile input to the commands other than ``run`` (sweep, tune, calibrate, compare, export, identify, excite, monitor
--log, report --rig, --save): each case is refused with its documented exit code, quickly, in bounded memory, in
one line, and the case's directory is as it was (nothing written, nothing replaced). The table of cases is
docs/hostile-input.md, "The other commands"; the harness (children forked from one interpreter that imported the
command line once, CPU time and peak RSS from ``os.wait4``) is tests/test_hostile_input.py's.
"""

from __future__ import annotations

import json
import os
import re
import socket
import stat
from pathlib import Path
from typing import NamedTuple

import pytest

from gantry_twin.inputs import INPUT_MAX_BYTES
from gantry_twin.sweep.engine import machine_cores

from .test_hostile_input import (
    DOC,
    HANG_LIMIT_S,
    RSS_LIMIT_MB,
    SWEEP,
    TIME_LIMIT_S,
    Case,
    Fifo,
    Link,
    Outcome,
    _log_csv,
    _make,
    run_children,
)

SECTION = "## The other commands"


class Socket(NamedTuple):
    """A Unix-domain socket bound at the path (nothing listens on it)."""


#: A run's summary.json as small as RunSummary reads (the fields it requires).
SUMMARY = {"schema_version": 1, "controller": "diarc", "duration_s": 1.0, "sample_period_s": 2e-4, "steps": 5000}
SUMMARY = json.dumps({**SUMMARY, "status": "ok"})
A_RUN = {"a/summary.json": SUMMARY}
CALIBRATION = """targets:
  - {label: C1, scenario: no_load_circle, controller: darc, rms_um: 2.03, max_um: 7.31}
free:
  - {name: vs_x, field: plant.friction.x.vs_m_s, range: [0.002, 0.05], start: 0.01}
"""
LOG = _log_csv(1.0)
BINARY = bytes(range(256)) * 4
DEEP_JSON = "[" * 100_000 + "]" * 100_000
BILLION = "{start: 0, stop: 1, num: 1000000000}"
SW = ("sweep", "w.yaml", "--out", "out")
#: A valid tune spec: the shipped PD baseline's.
TUNE = (Path(__file__).resolve().parents[1] / "tunes" / "pd_baseline.yaml").read_text(encoding="utf-8")
TU = ("tune", "t.yaml", "--out", "out")
CAL = ("calibrate", "c.yaml", "--out", "out")
CMP = ("compare", "a", "b", "--out", "out")
EXPORT = ("export", "trace.parquet", "--out", "x.csv")
ID = ("identify", "log.csv", "--out", "out")
MON = ("monitor", "--log", "log.csv", "--out", "out")
EXC = ("excite", "--out", "out", "--no-run")
RIG = ("report", "--rig", "rig.json", "--out", "out")
SAVE = ("run", "--set", "duration_s=0.01", "--no-plots", "--out", "out", "--save")
#: A directory no one may make (as root too): --out there cannot be written.
UNWRITABLE = "/proc/gantry-twin-out"


#: A regular file: a directory under it cannot be made, by root either (ENOTDIR), as a read-only folder cannot.
UNDER_A_FILE = {"afile": "x"}
#: An existing directory no one may write in, root included (a chmod 555 folder does not stop root).
NOT_WRITABLE = "/proc/sys"


def _trace(damaged: bool = False) -> bytes:
    """A small zstd-compressed Parquet trace; ``damaged``: the magic number of its first compressed page zeroed, so
    that reading its row group fails inside the decompression (the file's footer and metadata are intact)."""
    import io

    import pyarrow as pa
    import pyarrow.parquet as pq

    sink = io.BytesIO()
    table = pa.table({"t_s": [k * 2e-4 for k in range(500)], "x_m": [k * 1e-6 for k in range(500)]})
    pq.write_table(table, sink, compression="zstd", use_dictionary=False)
    data = bytearray(sink.getvalue())
    if damaged:
        at = data.index(b"\x28\xb5\x2f\xfd")  # zstd's frame magic, in the first data page
        data[at : at + 4] = bytes(4)
    return bytes(data)


def _summary(**changes: object) -> str:
    return json.dumps({**json.loads(SUMMARY), **changes})


def _sweep_of(count: int, last: str) -> str:
    """A sweep of ``count`` distinct payload masses, the last one ``last``."""
    values = [f"{k * 0.001:.3f}" for k in range(count - 1)] + [last]
    return f"scenario: no_load_circle\naxes:\n  - {{field: payload.mass_kg, values: [{', '.join(values)}]}}\n"


def _sweep_scenario(name: str) -> str:
    return f"scenario: {name}\naxes:\n  - {{field: payload.mass_kg, values: [0]}}\n"


CASES = [
    # sweep: the file, its points, the command line.
    Case("sweep_file_fifo", {"w.yaml": Fifo()}, SW),
    Case("sweep_file_dev_zero", {"w.yaml": Link("/dev/zero")}, SW),
    Case("sweep_file_binary", {"w.yaml": BINARY}, SW),
    Case("sweep_file_too_large", {"w.yaml": "#" * (INPUT_MAX_BYTES + 1)}, SW),
    Case("sweep_alias", {"w.yaml": SWEEP + "  - field: duration_s\n    values: &v [1, 2]\nrepeats: *v\n"}, SW),
    Case("sweep_deep", {"w.yaml": "scenario: no_load_circle\nset: " + "{a: " * 100 + "1" + "}" * 100 + "\n"}, SW),
    Case("sweep_unknown_key", {"w.yaml": SWEEP + "axis: []\n"}, SW),
    Case("sweep_a_billion_points", {"w.yaml": SWEEP.replace("values: [0, 1]", "linspace: " + BILLION)}, SW),
    Case("sweep_2000_points_the_last_bad", {"w.yaml": _sweep_of(2000, "-1")}, SW),
    Case("sweep_value_nan", {"w.yaml": _sweep_of(1, ".nan")}, SW),
    Case("sweep_field_a_path", {"w.yaml": "scenario: no_load_circle\naxes:\n  - {field: ../x, values: [0]}\n"}, SW),
    Case("sweep_scenario_missing", {"w.yaml": _sweep_scenario("nowhere.yaml")}, SW),
    Case("sweep_scenario_dev_zero", {"w.yaml": _sweep_scenario("f.yaml"), "f.yaml": Link("/dev/zero")}, SW),
    Case(
        "sweep_unknown_controller",
        {"w.yaml": "scenario: no_load_circle\nset: {controller.name: nosuchplugin}\n" + SWEEP.split("\n", 1)[1]},
        SW,
    ),
    Case("sweep_workers_1e20", {"w.yaml": SWEEP}, (*SW, "--workers", "1e20")),
    Case("sweep_workers_0", {"w.yaml": SWEEP}, (*SW, "--workers", "0")),
    Case("sweep_scheduler_port_99999", {"w.yaml": SWEEP}, (*SW, "--scheduler", "tcp://127.0.0.1:99999")),
    Case("sweep_resume_junk_results", {"w.yaml": SWEEP, "out/results.parquet": "junk\n"}, (*SW, "--resume")),
    Case("sweep_out_unwritable", {"w.yaml": SWEEP}, ("sweep", "w.yaml", "--out", UNWRITABLE)),
    Case("sweep_resume_into_unwritable", {"w.yaml": SWEEP}, ("sweep", "w.yaml", "--out", UNWRITABLE, "--resume")),
    Case("sweep_out_is_a_file", {"w.yaml": SWEEP, "afile": "x"}, ("sweep", "w.yaml", "--out", "afile")),
    # calibrate
    Case("calibrate_spec_fifo", {"c.yaml": Fifo()}, CAL),
    Case("calibrate_spec_dev_zero", {"c.yaml": Link("/dev/zero")}, CAL),
    Case("calibrate_spec_binary", {"c.yaml": BINARY}, CAL),
    Case("calibrate_spec_alias", {"c.yaml": "base: &b {duration_s: 1}\nmore: *b\n"}, CAL),
    Case("calibrate_spec_unknown_key", {"c.yaml": CALIBRATION + "budget: 3\n"}, CAL),
    Case("calibrate_range_inverted", {"c.yaml": CALIBRATION.replace("[0.002, 0.05]", "[0.05, 0.002]")}, CAL),
    Case("calibrate_start_outside_its_range", {"c.yaml": CALIBRATION.replace("start: 0.01", "start: 9")}, CAL),
    Case("calibrate_target_nan", {"c.yaml": CALIBRATION.replace("rms_um: 2.03", "rms_um: .nan")}, CAL),
    Case("calibrate_evaluations_0", {"c.yaml": CALIBRATION}, (*CAL, "--evaluations", "0")),
    Case("calibrate_evaluations_of_20_digits", {"c.yaml": CALIBRATION}, (*CAL, "--evaluations", "9" * 20)),
    Case("calibrate_workers_past_the_cores", {"c.yaml": CALIBRATION}, (*CAL, "--workers", "100000")),
    Case("calibrate_scheduler_not_an_address", {"c.yaml": CALIBRATION}, (*CAL, "--scheduler", "notaurl")),
    Case("calibrate_out_unwritable", {"c.yaml": CALIBRATION}, ("calibrate", "c.yaml", "--out", UNWRITABLE)),
    Case("calibrate_out_is_a_file", {"c.yaml": CALIBRATION, "afile": "x"}, ("calibrate", "c.yaml", "--out", "afile")),
    # compare: the runs' summary.json and latest.
    Case("compare_one_run", A_RUN, ("compare", "a", "--out", "out")),
    Case("compare_missing_run", A_RUN, CMP),
    Case("compare_summary_deep_json", {**A_RUN, "b/summary.json": DEEP_JSON}, CMP),
    Case("compare_summary_wrong_type", {**A_RUN, "b/summary.json": _summary(steps="many")}, CMP),
    Case("compare_summary_nan", {**A_RUN, "b/summary.json": SUMMARY.replace("1.0", "NaN")}, CMP),
    Case("compare_summary_too_large", {**A_RUN, "b/summary.json": " " * (INPUT_MAX_BYTES + 1)}, CMP),
    Case("compare_summary_binary", {**A_RUN, "b/summary.json": BINARY}, CMP),
    Case("compare_summary_fifo", {**A_RUN, "b/summary.json": Fifo()}, CMP),
    Case("compare_summary_not_an_object", {**A_RUN, "b/summary.json": "[1, 2]"}, CMP),
    Case("compare_summary_other_schema", {**A_RUN, "b/summary.json": _summary(schema_version=99)}, CMP),
    Case("compare_latest_of_8_mb", {**A_RUN, "b/latest": "a" * (8 << 20)}, CMP),
    Case("compare_latest_binary", {**A_RUN, "b/latest": bytes(range(256))}, CMP),
    Case("compare_latest_fifo", {**A_RUN, "b/latest": Fifo()}, CMP),
    Case("compare_latest_names_a_path", {**A_RUN, "b/latest": "../a\n"}, CMP),
    Case("compare_out_is_a_file", {**A_RUN, "c/summary.json": SUMMARY, "f": "x"}, ("compare", "a", "c", "--out", "f")),
    # export: the run read, the CSV written.
    Case("export_run_fifo", {"trace.parquet": Fifo()}, EXPORT),
    Case("export_run_dev_zero", {"trace.parquet": Link("/dev/zero")}, EXPORT),
    Case("export_run_missing", {}, ("export", "nowhere", "--out", "x.csv")),
    Case("export_run_junk", {"trace.parquet": "junk\n"}, EXPORT),
    Case("export_run_footer_lies", {"trace.parquet": b"PAR1" + BINARY + b"PAR1"}, EXPORT),
    Case("export_run_without_trace", {"r/summary.json": SUMMARY}, ("export", "r", "--out", "x.csv")),
    Case("export_latest_binary", {"r/latest": bytes(range(256))}, ("export", "r", "--out", "x.csv")),
    Case("export_out_socket", {"trace.parquet": "junk\n", "x.csv": Socket()}, EXPORT),
    Case("export_out_symlink_to_dev_null", {"trace.parquet": "junk\n", "x.csv": Link("/dev/null")}, EXPORT),
    # identify: the logs and options.
    Case("identify_log_fifo", {"log.csv": Fifo()}, ID),
    Case("identify_log_dev_zero", {"log.csv": Link("/dev/zero")}, ID),
    Case("identify_log_binary", {"log.csv": BINARY}, ID),
    Case("identify_log_missing", {}, ID),
    Case("identify_log_t_in_milliseconds", {"log.csv": _log_csv(1000.0)}, ID),
    Case("identify_log_missing_column", {"log.csv": "t_s,u_x_v,u_y_v,x_m\n0,0,0,0\n"}, ID),
    Case("identify_log_nan", {"log.csv": LOG.replace("\n0.0004,0.0,", "\n0.0004,nan,")}, ID),
    Case("identify_log_header_over_64_kib", {"log.csv": "t" * 70_000 + "\n"}, ID),
    Case("identify_log_junk_parquet", {"log.parquet": b"PAR1junkjunkPAR1"}, ("identify", "log.parquet", "--out", "o")),
    Case("identify_filter_hz_nan", {"log.csv": LOG}, (*ID, "--filter-hz", "nan")),
    Case("identify_window_s_inf", {"log.csv": LOG}, (*ID, "--window-s", "inf")),
    Case("identify_out_is_a_file", {"log.csv": LOG, "afile": "x"}, ("identify", "log.csv", "--out", "afile")),
    # excite: the options and the plant file.
    Case("compile_controller_unknown", {}, ("compile", "--controller", "pd", "--controller", "nope")),
    Case("excite_duration_1e308", {}, (*EXC, "--duration-s", "1e308")),
    Case("excite_duration_1e5", {}, (*EXC, "--duration-s", "1e5")),
    Case("excite_duration_negative", {}, (*EXC, "--duration-s", "-1")),
    Case("excite_fade_longer_than_the_run", {}, (*EXC, "--duration-s", "2", "--fade-s", "5")),
    Case("excite_payload_negative", {}, (*EXC, "--payload-kg", "-1")),
    Case("excite_plant_fifo", {"p.xml": Fifo()}, (*EXC, "--plant", "p.xml")),
    Case("excite_plant_dev_zero", {"p.xml": Link("/dev/zero")}, (*EXC, "--plant", "p.xml")),
    Case("excite_plant_binary", {"p.xml": BINARY}, (*EXC, "--plant", "p.xml")),
    Case("excite_plant_of_40_mb", {"p.xml": "<mujoco>" + " " * (40 << 20) + "</mujoco>"}, (*EXC, "--plant", "p.xml")),
    Case("excite_plant_not_a_gantry", {"p.xml": "<mujoco><worldbody/></mujoco>"}, (*EXC, "--plant", "p.xml")),
    Case("excite_out_is_a_file", {"afile": "x"}, ("excite", "--out", "afile", "--no-run")),
    # monitor --log
    Case("monitor_log_fifo", {"log.csv": Fifo()}, MON),
    Case("monitor_log_dev_zero", {"log.csv": Link("/dev/zero")}, MON),
    Case("monitor_log_binary", {"log.csv": BINARY}, MON),
    Case("monitor_log_positions_in_mm", {"log.csv": LOG.replace(",0.0,0.0\n", ",0.0,400.0\n")}, MON),
    Case("monitor_log_baseline_fifo", {"log.csv": LOG, "b.json": Fifo()}, (*MON, "--baseline", "b.json")),
    Case("monitor_log_baseline_deep_json", {"log.csv": LOG, "b.json": DEEP_JSON}, (*MON, "--baseline", "b.json")),
    Case("monitor_log_scenario_fifo", {"log.csv": LOG, "s.yaml": Fifo()}, ("monitor", "s.yaml", *MON[1:])),
    Case("monitor_log_set_bad", {"log.csv": LOG}, (*MON, "--set", "duration_s=-1")),
    Case(
        "monitor_log_out_unwritable",
        {"log.csv": LOG},
        ("monitor", "--log", "log.csv", "--out", UNWRITABLE, "--set", "monitor.baseline_window_s=[0, 0.02]"),
    ),
    Case(
        "monitor_log_out_is_a_file", {"log.csv": LOG, "afile": "x"}, ("monitor", "--log", "log.csv", "--out", "afile")
    ),
    # tune: the spec, the command line, the study to resume.
    Case("tune_file_fifo", {"t.yaml": Fifo()}, TU),
    Case("tune_file_dev_zero", {"t.yaml": Link("/dev/zero")}, TU),
    Case("tune_file_binary", {"t.yaml": BINARY}, TU),
    Case("tune_file_too_large", {"t.yaml": "#" * (INPUT_MAX_BYTES + 1)}, TU),
    Case("tune_unknown_key", {"t.yaml": TUNE + "bogus: 1\n"}, TU),
    Case("tune_a_billion_trials", {"t.yaml": TUNE.replace("trials: 60", "trials: 1000000000")}, TU),
    Case("tune_design_range_empty", {"t.yaml": TUNE.replace("low: 1000, high: 100000", "low: 100000, high: 1000")}, TU),
    Case(
        "tune_member_payload_nan",
        {"t.yaml": TUNE.replace("rig, payload.mass_kg: 0}", "rig, payload.mass_kg: .nan}")},
        TU,
    ),
    Case("tune_workers_0", {"t.yaml": TUNE}, (*TU, "--workers", "0")),
    Case("tune_trials_0", {"t.yaml": TUNE}, (*TU, "--trials", "0")),
    Case("tune_scheduler_notaurl", {"t.yaml": TUNE}, (*TU, "--scheduler", "notaurl")),
    Case("tune_out_unwritable", {"t.yaml": TUNE}, ("tune", "t.yaml", "--out", UNWRITABLE)),
    Case("tune_out_holds_a_study", {"t.yaml": TUNE, "out/study.db": "junk\n"}, TU),
    Case("tune_resume_junk_study", {"t.yaml": TUNE, "out/study.db": "junk\n"}, (*TU, "--resume")),
    Case("tune_resume_study_a_fifo", {"t.yaml": TUNE, "out/study.db": Fifo()}, (*TU, "--resume")),
    # report --rig
    Case("report_rig_fifo", {"rig.json": Fifo()}, RIG),
    Case("report_rig_dev_zero", {"rig.json": Link("/dev/zero")}, RIG),
    Case("report_rig_binary", {"rig.json": BINARY}, RIG),
    Case("report_rig_deep_json", {"rig.json": DEEP_JSON}, RIG),
    Case("report_rig_too_large", {"rig.json": " " * (INPUT_MAX_BYTES + 1)}, RIG),
    Case("report_rig_not_json", {"rig.json": "overrides: [a=1]\n"}, RIG),
    Case("report_rig_overrides_not_a_list", {"rig.json": '{"overrides": "plant.model=rig"}'}, RIG),
    Case("report_rig_override_unknown_field", {"rig.json": '{"overrides": ["plant.nosuch=1"]}'}, RIG),
    # Every command that writes: its output location checked before any work (a regular file in the way, or a folder
    # no one may write in), one line, exit 2.
    Case("run_out_under_a_file", UNDER_A_FILE, ("run", "--set", "duration_s=0.01", "--no-plots", "--out", "afile/d")),
    Case("run_out_not_writable", {}, ("run", "--set", "duration_s=0.01", "--no-plots", "--out", NOT_WRITABLE)),
    Case(
        "monitor_out_under_a_file",
        UNDER_A_FILE,
        ("monitor", "no_load_circle", "--set", "duration_s=0.1", "--set", "monitor.baseline_window_s=[0, 0.05]")
        + ("--no-plots", "--out", "afile/d"),
    ),
    Case("report_out_under_a_file", UNDER_A_FILE, ("report", "--out", "afile/d")),
    Case("report_out_not_writable", {}, ("report", "--out", NOT_WRITABLE)),
    Case("sweep_out_not_writable", {"w.yaml": SWEEP}, ("sweep", "w.yaml", "--out", NOT_WRITABLE)),
    Case(
        "calibrate_out_under_a_file",
        {"c.yaml": CALIBRATION, **UNDER_A_FILE},
        ("calibrate", "c.yaml", "--out", "afile/d"),
    ),
    Case("tune_out_under_a_file", {"t.yaml": TUNE, **UNDER_A_FILE}, ("tune", "t.yaml", "--out", "afile/d")),
    Case("identify_out_under_a_file", {"log.csv": LOG, **UNDER_A_FILE}, ("identify", "log.csv", "--out", "afile/d")),
    Case("identify_out_not_writable", {"log.csv": LOG}, ("identify", "log.csv", "--out", NOT_WRITABLE)),
    Case("excite_out_under_a_file", UNDER_A_FILE, ("excite", "--out", "afile/d")),
    Case("export_out_under_a_file", {"trace.parquet": _trace(), **UNDER_A_FILE}, (*EXPORT[:3], "afile/x.csv")),
    Case("export_out_not_writable", {"trace.parquet": _trace()}, (*EXPORT[:3], f"{NOT_WRITABLE}/x.csv")),
    Case(
        "compare_out_under_a_file",
        {**A_RUN, "c/summary.json": SUMMARY, **UNDER_A_FILE},
        (*CMP[:2], "c", "--out", "afile/d"),
    ),
    Case("monitor_log_out_under_a_file", {"log.csv": LOG, **UNDER_A_FILE}, (*MON[:3], "--out", "afile/d")),
    Case("serve_out_under_a_file", UNDER_A_FILE, ("serve", "--port", "0", "--realtime", "max", "--out", "afile/d")),
    Case("serve_out_not_writable", {}, ("serve", "--port", "0", "--realtime", "max", "--out", NOT_WRITABLE)),
    # A damaged trace: blamed on the trace, not on --out.
    Case("export_run_damaged_page", {"trace.parquet": _trace(damaged=True)}, EXPORT),
    # validate and runs
    Case("validate_fifo", {"s.yaml": Fifo()}, ("validate", "s.yaml")),
    Case("validate_dev_zero", {"s.yaml": Link("/dev/zero")}, ("validate", "s.yaml")),
    Case("validate_binary_then_good", {"s.yaml": "{}\n", "t.yaml": BINARY}, ("validate", "t.yaml", "s.yaml")),
    Case("runs_prune_keep_negative", {}, ("runs", "--prune", "--keep", "-1")),
    # --save (run and monitor): never into something that is not a regular file.
    Case("save_to_fifo", {"r.rrd": Fifo()}, (*SAVE, "r.rrd")),
    Case("save_to_directory", {"r.rrd/x": "x"}, (*SAVE, "r.rrd")),
    Case("save_to_symlink_to_dev_null", {"r.rrd": Link("/dev/null")}, (*SAVE, "r.rrd")),
    Case("save_to_socket", {"r.rrd": Socket()}, (*SAVE, "r.rrd")),
    Case("save_in_a_missing_directory", {}, (*SAVE, "nodir/r.rrd")),
]


def make(directory: Path, files: dict[str, object]) -> None:
    """The case's files (tests/test_hostile_input.py's kinds, and sockets)."""
    _make(directory, {k: v for k, v in files.items() if not isinstance(v, Socket)})
    for name, content in files.items():
        if isinstance(content, Socket):
            with socket.socket(socket.AF_UNIX) as bound:
                bound.bind(str(directory / name))


def snapshot(directory: Path) -> dict[str, tuple[int, int, int, int]]:
    """Every path under ``directory`` (symlinks not followed): (kind and mode, size, inode, mtime ns)."""
    found = {}
    for root, dirs, files in os.walk(directory):
        for name in dirs + files:
            path = Path(root, name)
            info = os.lstat(path)
            found[str(path.relative_to(directory))] = (info.st_mode, info.st_size, info.st_ino, info.st_mtime_ns)
    return found


def documented() -> dict[str, tuple[int, str]]:
    """case id -> (exit code, the one-line answer) from the table under SECTION in docs/hostile-input.md."""
    text = DOC.read_text(encoding="utf-8").split(SECTION, 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `([^`]+)` \| .* \| (\d+) \| `(.*)` \|$", text, flags=re.MULTILINE)
    return {case: (int(code), answer.replace("<cores>", str(machine_cores()))) for case, code, answer in rows}


def matches(line: str, answer: str) -> bool:
    """The answer as documented; ``<path>`` in it stands for this machine's absolute path of a case's file,
    ``<key>`` for a sweep plan's key (a digest of the resolved scenario: it changes with the schema)."""
    parts = re.split(r"<path>|<key>", answer)
    return re.fullmatch(".*?".join(re.escape(part) for part in parts), line) is not None


class Ran(NamedTuple):
    outcome: Outcome
    before: dict
    after: dict


@pytest.fixture(scope="module")
def ran(tmp_path_factory) -> dict[str, Ran]:
    root = tmp_path_factory.mktemp("hostile_commands")
    for case in CASES:
        make(root / case.id, case.files)
    before = {c.id: snapshot(root / c.id) for c in CASES}
    outcomes = run_children(CASES, root, "fork")
    return {c.id: Ran(outcomes[c.id], before[c.id], snapshot(root / c.id)) for c in CASES}


def test_at_least_60_cases_across_the_commands_each_documented():
    assert len(CASES) >= 60 and len({c.id for c in CASES}) == len(CASES)
    assert set(documented()) == {c.id for c in CASES}
    commands = {c.args[0] if c.args[0] != "report" else "report --rig" for c in CASES}
    commands |= {"monitor --log" for c in CASES if "--log" in c.args} | {"--save" for c in CASES if "--save" in c.args}
    assert {
        "sweep",
        "tune",
        "calibrate",
        "compare",
        "export",
        "identify",
        "excite",
        "monitor --log",
        "report --rig",
    } <= commands
    assert "--save" in commands


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_refused_with_its_exit_code_one_line_quickly_small_nothing_written_or_replaced(ran, case):
    o, before, after = ran[case.id]
    code, answer = documented()[case.id]
    assert o.code == code, o
    assert o.cpu_s < TIME_LIMIT_S, o.cpu_s
    assert o.wall_s < HANG_LIMIT_S, o.wall_s
    assert o.peak_rss_mb < RSS_LIMIT_MB, o.peak_rss_mb
    assert "Traceback" not in o.stderr and o.stdout == ""
    lines = o.stderr.strip().splitlines()
    assert len(lines) == 1 and len(lines[0]) < 400, o.stderr[:1000]
    assert matches(lines[0], answer), lines[0]
    assert after == before  # nothing written, nothing replaced, nothing touched (a FIFO or socket too)


def test_the_case_files_are_what_they_say():
    """The harness's kinds of file are made as named (a case of a FIFO that was a plain file would prove nothing)."""
    case = next(c for c in CASES if c.id == "export_out_socket")
    root = Path(os.environ.get("TMPDIR", "/tmp")) / f"gantry-twin-kinds-{os.getpid()}"
    try:
        make(root, {**case.files, "f": Fifo()})
        assert stat.S_ISSOCK(os.lstat(root / "x.csv").st_mode) and stat.S_ISFIFO(os.lstat(root / "f").st_mode)
    finally:
        for p in root.iterdir():
            p.unlink()
        root.rmdir()


def test_serve_web_without_the_viewer_binary_exit_2_one_line_nothing_written(tmp_path, capsys, monkeypatch):
    """Once a FileNotFoundError traceback (exit 1) from starting the missing binary."""
    from .helpers import run_main

    monkeypatch.setenv("RERUN_CLI_PATH", str(tmp_path / "no-rerun"))
    out = tmp_path / "out"
    code, stdout, err = run_main(["run", "--set", "duration_s=0.01", "--out", str(out), "--serve-web"], capsys)
    assert code == 2 and stdout == ""
    assert err.strip().splitlines() == [
        f"gantry-twin: error: RERUN_CLI_PATH {tmp_path / 'no-rerun'}: not an executable file (the rerun viewer binary)"
    ]
    assert sorted(p.name for p in tmp_path.iterdir()) == []


#: The commands that compile (or load) the loops, each as a user would give it; NUMBA_CACHE_DIR is checked first.
COMPILING = [
    ("run", "--set", "duration_s=0.01", "--no-plots", "--out", "out"),
    ("sweep", "w.yaml", "--out", "out"),
    ("report", "--out", "out"),
    ("compile",),
    ("monitor", "--log", "log.csv", "--out", "out"),
    ("excite", "--out", "out"),
]


@pytest.mark.parametrize("argv", COMPILING, ids=[a[0] if a[0] != "monitor" else "monitor_log" for a in COMPILING])
def test_an_unwritable_numba_cache_dir_is_refused_at_once_naming_the_variable(tmp_path, argv):
    """NUMBA_CACHE_DIR where no folder can be made (under a regular file: ENOTDIR, for root too; a ``chmod 555``
    folder does not stop root, which the tests run as). Each command that compiles refuses it before any work, in a
    fresh process (the variable is read at import): exit 2, one line naming the variable and the folder, nothing
    written in the case's directory or beside the package's sources (numba's silent fallback cache, once). Before
    this check: a sweep failed each point after minutes, ``run`` compiled into the package's ``__pycache__``."""
    import subprocess
    import sys

    src = Path(__file__).resolve().parents[1] / "src"
    (tmp_path / "afile").write_text("x")
    (tmp_path / "w.yaml").write_text(SWEEP)
    (tmp_path / "log.csv").write_text(LOG)
    before = snapshot(tmp_path)
    pycache = sorted(str(p) for p in src.rglob("*.nbi"))
    env = {**os.environ, "PYTHONPATH": str(src), "NUMBA_CACHE_DIR": str(tmp_path / "afile" / "numba")}
    done = subprocess.run(
        [sys.executable, "-m", "gantry_twin", *argv], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120
    )
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and done.stdout == "", done.stderr[-2000:]
    assert len(lines) == 1, done.stderr[-2000:]
    assert re.fullmatch(
        rf"gantry-twin: error: NUMBA_CACHE_DIR: the compiled-kernel cache {re.escape(str(tmp_path))}/afile/numba/"
        r"[0-9a-f]{16} cannot be made or written \(Not a directory\); set NUMBA_CACHE_DIR to a writable folder",
        lines[0],
    ), lines[0]
    assert snapshot(tmp_path) == before
    assert sorted(str(p) for p in src.rglob("*.nbi")) == pycache


def test_commands_that_compile_nothing_ignore_an_unwritable_numba_cache_dir(tmp_path):
    """``validate`` (and the other commands that run no kernel) do not refuse a bad NUMBA_CACHE_DIR: they need none."""
    import subprocess
    import sys

    src = Path(__file__).resolve().parents[1] / "src"
    (tmp_path / "afile").write_text("x")
    env = {**os.environ, "PYTHONPATH": str(src), "NUMBA_CACHE_DIR": str(tmp_path / "afile" / "numba")}
    done = subprocess.run(
        [sys.executable, "-m", "gantry_twin", "validate", "no_load_circle"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0 and ": ok (diarc, circle, 30 s)" in done.stdout, done.stderr[-2000:]
