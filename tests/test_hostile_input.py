"""Hostile input: each case is refused by a child process with exit 2, quickly, in bounded
memory, in one line, writing nothing. The table of cases is docs/hostile-input.md.

Each case runs in a child forked from one fresh interpreter that imported the CLI once (the imports take about
a second: forking keeps the test short); the three cases that once ran away also run end to end in fresh processes.
Peak RSS and CPU time come from ``os.wait4``. "Quickly" is CPU time (user + system), which the neighbours on a
shared machine do not change; wall time is bounded separately and loosely, to catch a case that blocks (a FIFO
read uses no CPU). A 4 GiB address-space limit on each child is only a safety net for this machine
should a case regress (e.g. reading /dev/zero): the assertions are on the measured time and peak RSS.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import NamedTuple

import pytest

from gantry_twin.inputs import INPUT_MAX_BYTES
from gantry_twin.scenario.loading import INPUT_MAX_DEPTH
from gantry_twin.sweep.engine import machine_cores

DOC = Path(__file__).resolve().parents[1] / "docs" / "hostile-input.md"
#: What every case must stay within: CPU seconds (start-up included), and a wall-clock bound for a blocked read.
TIME_LIMIT_S = 5.0
HANG_LIMIT_S = 30.0
RSS_LIMIT_MB = 300.0
#: The default command: the scenario file s.yaml, outputs to out/ (which must not appear).
RUN = ("run", "s.yaml", "--out", "out")


class Link(NamedTuple):
    target: str


class Fifo(NamedTuple):
    pass


class Case(NamedTuple):
    """files: name -> text, bytes, Link or Fifo, made in the case's own directory (the child's cwd)."""

    id: str
    files: dict[str, object]
    args: tuple[str, ...] = RUN


def _alias_bomb() -> str:
    """The nested alias bomb inside a field: nine aliases of nine aliases ... nine levels deep."""
    text = "window_s:\n  - &a0 [1, 2, 3, 4, 5, 6, 7, 8, 9]\n"
    for i in range(1, 10):
        text += f"  - &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]\n"
    return text


def _unknown_keys(megabytes: float) -> str:
    lines, size, i = [], 0, 0
    while size < megabytes * 1e6:
        line = f"unknown_key_{i}: {i}\n"
        lines.append(line)
        size += len(line)
        i += 1
    return "".join(lines)


MONITORED = "monitor: {enable: true, baseline_summary: %s}\n"
#: ``export`` of a (junk) trace to an --out that follows; a sweep file and its command.
EXPORT = ("export", "trace.parquet", "--csv", "--out")
SWEEP = "scenario: no_load_circle\naxes:\n  - {field: payload.mass_kg, values: [0, 1]}\n"
SWEEP_RUN = ("sweep", "w.yaml", "--out", "out")


def _log_csv(t_scale: float, rows: int = 200) -> str:
    """A log of still axes at the machine's 0.2 ms, its t_s multiplied by ``t_scale`` (1000: milliseconds)."""
    lines = ["t_s,u_x_v,u_y_v,x_m,y_m"] + [f"{k * 2e-4 * t_scale!r},0.0,0.0,0.0,0.0" for k in range(rows)]
    return "\n".join(lines) + "\n"


#: Past our nesting limit, and past libyaml's own (1000).
DEEP, DEEPER = INPUT_MAX_DEPTH * 5, 1001

CASES = [
    # Files that are not scenario files: refused before reading.
    Case("dev_zero_symlink", {"s.yaml": Link("/dev/zero")}),
    Case("dev_null", {}, ("run", "/dev/null", "--out", "out")),
    Case("fifo", {"s.yaml": Fifo()}),
    Case("symlink_loop", {"s.yaml": Link("s.yaml")}),
    Case("dangling_symlink", {"s.yaml": Link("nowhere.yaml")}),
    Case("unknown_keys_50mb", {"s.yaml": _unknown_keys(50)}),
    Case("comments_over_the_cap", {"s.yaml": "#" * (INPUT_MAX_BYTES + 1)}),
    Case("binary_data", {"s.yaml": bytes(range(256)) * 4}),
    Case("utf16_bom", {"s.yaml": "duration_s: 3\n".encode("utf-16")}),
    Case("nul_byte", {"s.yaml": b"duration_s: 3\x00\n"}),
    # YAML that would expand or nest without bound.
    Case("alias_bomb_in_field", {"s.yaml": _alias_bomb()}),
    Case("alias_of_a_mapping", {"s.yaml": "payload: &p {mass_kg: 1}\nchanges: {payload_change: [*p]}\n"}),
    Case("merge_key", {"s.yaml": "contour: &c {radius_m: 0.1}\nmonitor: {<<: *c}\n"}),
    Case("deep_list", {"s.yaml": "window_s: " + "[" * DEEP + "]" * DEEP + "\n"}),
    Case("deep_mapping", {"s.yaml": "payload: " + "{a: " * DEEPER + "1" + "}" * DEEPER + "\n"}),
    # Other YAML oddities.
    Case("utf8_bom_then_bad_field", {"s.yaml": "\ufeffdurations: 3\n"}),
    Case("duplicate_nested_key", {"s.yaml": "payload: {mass_kg: 1, mass_kg: 2}\n"}),
    Case("python_tag", {"s.yaml": "duration_s: !!python/object/apply:os.system ['echo hi']\n"}),
    Case("local_tag", {"s.yaml": "duration_s: !seconds 3\n"}),
    Case("two_documents", {"s.yaml": "duration_s: 3\n---\nduration_s: 4\n"}),
    Case("date_as_number", {"s.yaml": "duration_s: 2024-01-01\n"}),
    # Bad numbers and sizes inside valid YAML.
    Case("integer_of_5000_digits", {"s.yaml": "duration_s: " + "1" * 5000 + "\n"}),
    Case("hex_beyond_float", {"s.yaml": "duration_s: 0x" + "f" * 400 + "\n"}),
    Case("float_1.0e400", {"s.yaml": "payload: {mass_kg: 1.0e+400}\n"}),
    Case("minus_inf", {"s.yaml": "duration_s: -.inf\n"}),
    Case("list_of_50k_numbers", {"s.yaml": "window_s: [" + ", ".join(["1"] * 50_000) + "]\n"}),
    Case("string_of_200k_chars", {"s.yaml": "duration_s: " + "x" * 200_000 + "\n"}),
    Case("key_of_200k_chars", {"s.yaml": "k" * 200_000 + ": 1\n"}),
    Case("unknown_key_of_1000_chars", {"s.yaml": "k" * 1000 + ": 1\n"}),
    # name and outputs.dir are labels, never paths.
    Case("name_parent_dir", {"s.yaml": "name: ../x\n"}, ("run", "s.yaml")),
    Case("name_absolute_path", {"s.yaml": "name: /dev/null/x\n"}, ("run", "s.yaml")),
    Case("name_dot_dot", {"s.yaml": "name: ..\n"}, ("run", "s.yaml")),
    Case("name_too_long", {"s.yaml": f"name: {'n' * 65}\n"}, ("run", "s.yaml")),
    Case("outputs_dir_path", {"s.yaml": "outputs: {dir: ../elsewhere}\n"}, ("run", "s.yaml")),
    # Pathological settings.
    Case("filter_hz_1.0e-300", {"s.yaml": "controller: {options: {estimator: {filter_hz: [1.0e-300, 50]}}}\n"}),
    Case("forgetting_1.0e300", {"s.yaml": "controller: {options: {estimator: {least_squares: {kappa: 1.0e+300}}}}\n"}),
    Case("ks_1.0e-300", {"s.yaml": "controller: {name: drc, options: {gains: {ks_v_s_m: [1.0e-300, 60]}}}\n"}),
    Case("encoder_resolution_1.0e-320", {"s.yaml": "sensing: {resolution_m: 1.0e-320}\n"}),
    # Files the scenario names.
    Case("baseline_summary_dev_zero", {"s.yaml": MONITORED % "/dev/zero"}),
    Case("baseline_summary_deep_json", {"s.yaml": MONITORED % "b.json", "b.json": "[" * 100_000 + "]" * 100_000}),
    Case("baseline_summary_too_large", {"s.yaml": MONITORED % "b.json", "b.json": " " * (INPUT_MAX_BYTES + 1)}),
    # The command line.
    Case("set_index_out_of_range", {"s.yaml": "{}\n"}, (*RUN, "--set", "disturbance.y.99.value_v=1")),
    Case("set_path_of_1000_parts", {"s.yaml": "{}\n"}, (*RUN, "--set", ".".join(["a"] * 1000) + "=1")),
    Case("set_value_alias", {"s.yaml": "{}\n"}, (*RUN, "--set", "window_s=[&a 1, *a]")),
    Case("set_value_nan", {"s.yaml": "{}\n"}, (*RUN, "--set", "duration_s=.nan")),
    Case("set_value_deep", {"s.yaml": "{}\n"}, (*RUN, "--set", "window_s=" + "[" * DEEP + "]" * DEEP)),
    Case("controller_name_of_10k_chars", {"s.yaml": "{}\n"}, (*RUN, "--controller", "c" * 10_000)),
    Case("out_is_a_file", {"s.yaml": "{}\n", "afile": "x"}, ("run", "s.yaml", "--out", "afile")),
    Case("jobs_of_5000_digits", {}, ("report", "--jobs", "9" * 5000, "--out", "out")),
    # Outputs that are not regular files: never replaced (nothing read or written first).
    Case("export_out_fifo", {"trace.parquet": "junk\n", "x.csv": Fifo()}, EXPORT + ("x.csv",)),
    Case("export_out_dev_null", {"trace.parquet": "junk\n"}, EXPORT + ("/dev/null",)),
    Case("export_out_directory", {"trace.parquet": "junk\n", "d": Link(".")}, EXPORT + ("d",)),
    # Resources a typo could exhaust, and addresses that are none.
    Case("sweep_workers_of_20_digits", {"w.yaml": SWEEP}, (*SWEEP_RUN, "--workers", "9" * 20)),
    Case("sweep_workers_past_the_cores", {"w.yaml": SWEEP}, (*SWEEP_RUN, "--workers", "100000")),
    Case("sweep_scheduler_not_an_address", {"w.yaml": SWEEP}, (*SWEEP_RUN, "--scheduler", "notaurl")),
    # Part programs (docs/gcode.md): bounded execution, and each malformed construct in one line with its column.
    *(
        Case(f"gcode_{name}", {"p.ngc": text}, ("validate", "p.ngc"))
        for name, text in (
            ("endless_loop", "G1 F600\no1 while [1]\n  X1\n  X0\no1 endwhile\n"),
            ("endless_recursion", "o<r> sub\n  o<r> call\no<r> endsub\no<r> call\n"),
            ("unclosed_bracket", "G1 X[1+2 F100\n"),
            ("unknown_function", "G1 X[COSH[1]] F100\n"),
            ("endwhile_without_while", "G1 X1 F100\no1 endwhile\n"),
            ("call_of_a_missing_subroutine", "o<pocket> call [1]\n"),
            ("g41_without_a_tool", "G41 G1 X10 F100\n"),
            (
                "nurbs_of_endless_points",
                "#1=0\nG5.2 X0 Y1 P1 F600\no1 while [1]\n  #1=[#1+1]\n  X[#1 MOD 100] Y1 P1\no1 endwhile\n",
            ),
            ("nurbs_order_in_the_thousands", "G5.2 X1 Y1 P1 L5000 F600\n"),
            ("spiral_of_a_hundred_million_turns", "G1 X10 F100\nG2 X10.001 Y0 I-10 J0 P99999999\n"),
        )
    ),
    # A log in other units than the machine's.
    Case(
        "monitor_log_t_in_milliseconds", {"log.csv": _log_csv(1000.0)}, ("monitor", "--log", "log.csv", "--out", "out")
    ),
]


class Outcome(NamedTuple):
    code: int
    stdout: str
    stderr: str
    wall_s: float  # the whole run of a fresh process, or start-up + the forked child's run
    cpu_s: float  # user + system seconds of the same
    peak_rss_mb: float  # measured, or for a forked child: start-up's peak + the child's growth
    written: list[str]
    child_wall_s: float = 0.0  # the forked child's (or fresh process's) own wall time, start-up not included


def _make(directory: Path, files: dict[str, object]) -> None:
    directory.mkdir()
    for name, content in files.items():
        path = directory / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, Link):
            path.symlink_to(content.target)
        elif isinstance(content, Fifo):
            os.mkfifo(path)
        elif isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(str(content), encoding="utf-8")


def _jobs(cases: list[Case], root: Path) -> str:
    return "".join(
        json.dumps({"cwd": str(d), "argv": list(c.args), "stdout": f"{d}.stdout", "stderr": f"{d}.stderr"}) + "\n"
        for c in cases
        for d in [root / c.id]
    )


def run_children(cases: list[Case], root: Path, mode: str) -> dict[str, Outcome]:
    """Each case in a child process (tests/hostile_children.py, one case at a time).

    ``fresh``: a new interpreter per case; its wall time and peak RSS as measured. ``fork``: children forked
    from one interpreter that imported the CLI once (the imports take about a second: doing them once keeps
    this test short); a case's time is the start-up's (from the start of that interpreter to the end of its
    imports) plus its child's, and its peak RSS the start-up's plus what its child added.
    """
    befores = {c.id: [p.name for p in (root / c.id).iterdir()] for c in cases}
    started = time.perf_counter()
    parent = subprocess.Popen(
        [sys.executable, str(CHILDREN), mode],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    startup = {"rss_kib": 0, "cpu_s": 0.0}
    startup_s = 0.0
    if mode == "fork":
        startup = json.loads(parent.stdout.readline() or "{}")
        startup_s = time.perf_counter() - started
    out, err = parent.communicate(_jobs(cases, root), timeout=600)
    lines = out.splitlines()
    assert parent.returncode == 0 and "rss_kib" in startup and len(lines) == len(cases), err[-3000:]
    outcomes = {}
    for case, line in zip(cases, lines, strict=True):
        r = json.loads(line)
        added_kib = max(r["maxrss_kib"] - r.get("start_rss_kib", 0), 0)
        d = root / case.id
        outcomes[case.id] = Outcome(
            r["code"],
            Path(f"{d}.stdout").read_text(errors="replace"),
            Path(f"{d}.stderr").read_text(errors="replace"),
            startup_s + r["wall_s"],
            startup["cpu_s"] + r["cpu_s"],
            (startup["rss_kib"] + added_kib) / 1024.0,
            [p.name for p in d.iterdir() if p.name not in befores[case.id]],
            r["wall_s"],
        )
    return outcomes


CHILDREN = Path(__file__).with_name("hostile_children.py")


@pytest.fixture(scope="module")
def hostile_root(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("hostile")


@pytest.fixture(scope="module")
def outcomes(hostile_root) -> dict[str, Outcome]:
    """Every case run once, each in its own forked child."""
    for case in CASES:
        _make(hostile_root / case.id, case.files)
    return run_children(CASES, hostile_root, "fork")


def test_nothing_written_beside_the_cases(hostile_root, outcomes):
    """A case that wrote outside its own directory (``name: ../x``) would leave something here."""
    expected = {name for c in CASES for name in (c.id, f"{c.id}.stdout", f"{c.id}.stderr")}
    assert {p.name for p in hostile_root.iterdir()} == expected


def documented_answers() -> dict[str, str]:
    """case id -> the one-line answer, from the table in docs/hostile-input.md (``<cores>``: this machine's)."""
    text = DOC.read_text(encoding="utf-8").split("## The other commands", 1)[0]  # that table: test_hostile_commands
    rows = re.findall(r"^\| `([^`]+)` \| .* \| `(.*)` \|$", text, flags=re.MULTILINE)
    return {case: answer.replace("<cores>", str(machine_cores())) for case, answer in rows}


def test_more_than_30_cases_each_documented():
    assert len(CASES) >= 30
    assert len({c.id for c in CASES}) == len(CASES)
    assert set(documented_answers()) == {c.id for c in CASES}


def assert_refused(o: Outcome, answer: str | None = None) -> None:
    """Exit 2 within 5 CPU s and 300 MB, one short stderr line, no traceback, nothing on stdout, nothing written."""
    assert o.code == 2, o
    assert o.cpu_s < TIME_LIMIT_S, o.cpu_s
    assert o.wall_s < HANG_LIMIT_S, o.wall_s
    assert o.peak_rss_mb < RSS_LIMIT_MB, o.peak_rss_mb
    assert "Traceback" not in o.stderr
    lines = o.stderr.strip().splitlines()
    assert len(lines) == 1 and len(lines[0]) < 400, o.stderr[:1000]
    assert o.stdout == ""
    assert o.written == [], o.written
    if answer is not None:
        assert lines[0] == answer


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_hostile_input_exit_2_quickly_small_one_line_nothing_written(outcomes, case):
    assert_refused(outcomes[case.id], documented_answers()[case.id])


#: The cases that once ran away: /dev/zero through a symlink (10.8 GB in 20 s before), the nested alias
#: bomb (6-9 GB, past 60 s) and 50 MB of unknown keys (1.4 GB, past 60 s).
REPRODUCTIONS = ("dev_zero_symlink", "alias_bomb_in_field", "unknown_keys_50mb")


@pytest.mark.parametrize("name", REPRODUCTIONS)
def test_runaway_cases_end_quickly_in_a_fresh_process(tmp_path, name):
    """The same cases end to end, start-up included, each alone in a fresh process."""
    case = next(c for c in CASES if c.id == name)
    _make(tmp_path / name, case.files)
    assert_refused(run_children([case], tmp_path, "fresh")[name], documented_answers()[name])
