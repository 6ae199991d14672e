"""Runs that never overwrite, kept and compared through the command line.

Acceptance: two runs of the same scenario without --out leave two complete run directories, and
``gantry-twin compare`` on them exits 0 and writes its table and plots.
"""

from __future__ import annotations

import json
import os
import shutil

import pytest

from gantry_twin import run as run_module
from gantry_twin.loop.trace import SimulationError
from gantry_twin.outputs.plots import FIGURES

from .helpers import run_main

#: 2 s runs with windows inside them (the default [T, 2T] of the circle needs 6.3 s).
OVERRIDES = ["duration_s=2", "window_s=[0.5, 1.5]", "estimates_window_s=[1.5, 2]"]
SHORT = [word for override in OVERRIDES for word in ("--set", override)]
RUN_DIR_FILES = {"summary.json", "scenario.yaml", "trace.parquet", "run_info.json", "plots"}


def run_dirs(base):
    """The run directories under runs/<name>/, the DIARC run first (names within a second sort at random)."""
    dirs = sorted(p for p in base.iterdir() if p.name != "latest")
    return sorted(dirs, key=lambda d: json.loads((d / "summary.json").read_text())["controller"] != "diarc")


def assert_one_line(err: str, *fragments: str) -> None:
    lines = [line for line in err.strip().splitlines() if "compiling the 0.2 ms loop" not in line]
    assert len(lines) == 1 and "Traceback" not in err, err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    """Two runs of no_load_circle without --out: DIARC, then DARC with 2.5 kg (in a scratch working directory)."""
    work = tmp_path_factory.mktemp("work")
    cwd = os.getcwd()
    os.chdir(work)
    try:
        first = run_main_plain(["run", "no_load_circle", *SHORT, "--no-progress"])
        second = run_main_plain(
            ["run", "no_load_circle", *SHORT, "--controller", "darc", "--set", "payload.mass_kg=2.5", "--no-progress"]
        )
    finally:
        os.chdir(cwd)
    return work, first, second


def run_main_plain(argv):
    """cli.main with stdout and stderr captured by hand (a module fixture cannot use capsys)."""
    import contextlib
    import io

    from gantry_twin.cli import app as cli

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(argv)
    return code, out.getvalue(), err.getvalue()


def test_two_runs_without_out_leave_two_complete_run_directories(two_runs):
    work, (code1, out1, err1), (code2, out2, err2) = two_runs
    assert code1 == 0 and code2 == 0, (err1, err2)
    base = work / "runs" / "no_load_circle"
    dirs = run_dirs(base)
    assert len(dirs) == 2
    for d in dirs:
        assert {p.name for p in d.iterdir()} == RUN_DIR_FILES, d
        assert json.loads((d / "summary.json").read_text())["status"] == "ok"
        assert sorted(p.name for p in (d / "plots").iterdir()) == sorted(FIGURES)
    # latest names the second run (the DARC one), by a relative link; the run printed where it went
    by_controller = {json.loads((d / "summary.json").read_text())["controller"]: d for d in dirs}
    assert os.readlink(base / "latest") == by_controller["darc"].name
    assert f"results in runs/no_load_circle/{by_controller['darc'].name}/ (" in out2
    assert f"results in runs/no_load_circle/{by_controller['diarc'].name}/ (" in out1
    second = json.loads((base / "latest" / "summary.json").read_text())
    assert second["controller"] == "darc" and second["controller_option"] == "darc"
    assert second["overrides"] == [*OVERRIDES, "payload.mass_kg=2.5"]
    first_line = out2.splitlines()[0]
    assert first_line.startswith("no_load_circle with darc on the rig plant (--set duration_s=2 ")
    assert "--set payload.mass_kg=2.5)" in first_line


def test_printed_summary_states_the_window_of_every_figure(two_runs):
    _, (_, out, _), _ = two_runs
    lines = out.splitlines()
    assert "contour error eps_c over [0.500, 1.500] s (window_s): rms " in lines[1]
    assert "contour error eps_c over [0.500, 2.000] s (whole run from the start of window_s): rms" in lines[2]
    assert lines[3].startswith("axial error e over [0.500, 2.000] s: rms x ")
    assert lines[4].startswith("command u over [0.000, 2.000] s: max |u| x ") and "at the limit x 0.00 %" in lines[4]
    assert lines[5].startswith("rms eps_c per period of 3.142 s from 0.000 s (1 period, the last up to the end): ")


def test_compare_writes_its_table_and_plots(two_runs, tmp_path, capsys):
    work, _, _ = two_runs
    base = work / "runs" / "no_load_circle"
    first, second = run_dirs(base)
    out = tmp_path / "cmp"
    code, stdout, err = run_main(["compare", str(first), str(base / "latest"), "--out", str(out)], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["compare.json", "compare.md", "plots"]
    assert sorted(p.name for p in (out / "plots").iterdir()) == sorted(FIGURES)
    table = json.loads((out / "compare.json").read_text())
    assert table["missing"] == []
    latest = (base / "latest").resolve()
    for column, directory in zip(table["runs"], (first, latest), strict=True):
        summary = json.loads((directory / "summary.json").read_text())
        figures = column["figures"]
        assert figures["controller"] == summary["controller"]
        assert figures["eps_c rms over window_s (um)"] == summary["contour_error_um"]["rms"]
        assert figures["eps_c max, whole run (um)"] == summary["whole_run"]["contour_error_um"]["max"]
        assert figures["e_y rms, whole run (um)"] == summary["whole_run"]["axial_error_rms_um"]["y"]
        assert figures["max abs(u_x), command window (V)"] == summary["whole_run"]["max_abs_command_v"]["x"]
        assert figures["health alarms"] == "no monitor"
    assert table["runs"][1]["figures"]["--set overrides"] == " ".join([*OVERRIDES, "payload.mass_kg=2.5"])
    markdown = (out / "compare.md").read_text()
    assert markdown in stdout and "| figure (window) | #1 | #2 |" in markdown
    assert "| M1 estimate / true (error) | " in markdown


def test_compare_without_out_writes_under_runs_compare(two_runs, tmp_path, capsys, monkeypatch):
    work, _, _ = two_runs
    monkeypatch.chdir(tmp_path)
    base = work / "runs" / "no_load_circle"
    code, stdout, err = run_main(["compare", *map(str, run_dirs(base))], capsys)
    assert code == 0, err
    (made,) = (tmp_path / "runs" / "compare").iterdir()
    assert (made / "compare.md").is_file() and f"written to runs/compare/{made.name}/" in stdout


def test_compare_names_the_figures_an_older_run_lacks(two_runs, tmp_path, capsys):
    work, _, _ = two_runs
    first, second = run_dirs(work / "runs" / "no_load_circle")
    old = tmp_path / "old"
    shutil.copytree(first, old)
    summary = json.loads((old / "summary.json").read_text())
    for key in ("whole_run", "contour_error_per_period_um", "overrides", "controller_option"):
        del summary[key]
    (old / "summary.json").write_text(json.dumps(summary))
    (old / "trace.parquet").unlink()
    code, stdout, err = run_main(["compare", str(old), str(second), "--out", str(tmp_path / "c")], capsys)
    assert code == 0, err
    notes = json.loads((tmp_path / "c" / "compare.json").read_text())["missing"]
    assert len(notes) == 2 and notes[0].startswith(f"#1 ({old}): summary.json lacks --set overrides, ")
    assert "eps_c rms, whole run (um)" in notes[0] and "eps_c rms per period" in notes[0]
    assert "no trace.parquet, not in the plots" in notes[1]
    assert "| eps_c rms, whole run (um) | missing | " in stdout
    assert "note: #1" in err
    assert sorted(p.name for p in (tmp_path / "c" / "plots").iterdir()) == sorted(FIGURES)  # the other run's


@pytest.mark.parametrize(
    ("case", "fragments"),
    [
        ("one_run", ("compare needs two runs or more",)),
        ("no_such", ("no_such: no such run directory",)),
        ("a_file", ("a_file: not a run directory",)),
        ("no_summary", ("no_summary: not a run directory: no summary.json",)),
        ("bad_json", ("summary.json: is not a run's summary.json (invalid JSON",)),
        ("not_ours", ("summary.json: is not a run's summary.json (input should be an object",)),
        ("out_is_a_file", ("--out", "exists and is not a directory")),
    ],
)
def test_compare_bad_input_exits_2_with_one_line(two_runs, tmp_path, capsys, case, fragments):
    work, _, _ = two_runs
    good = str(run_dirs(work / "runs" / "no_load_circle")[0])
    (tmp_path / "a_file").write_text("x")
    (tmp_path / "no_summary").mkdir()
    for name, text in (("bad_json", "{"), ("not_ours", "[1, 2]")):
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(text)
    out = tmp_path / "written"
    argv = {
        "one_run": [good],
        "out_is_a_file": [good, good],
    }.get(case, [good, str(tmp_path / case)])
    if case == "out_is_a_file":
        out = tmp_path / "a_file"
    code, _, err = run_main(["compare", *argv, "--out", str(out)], capsys)
    assert code == 2
    assert_one_line(err, "gantry-twin: error:", *fragments)
    assert not (tmp_path / "written").exists()


def test_a_run_that_fails_or_is_interrupted_leaves_latest_as_it_was(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    base = tmp_path / "runs" / "no_load_circle"
    args = ["run", *SHORT, "--set", "duration_s=0.5", "--set", "window_s=[0.1,0.5]", "--set",
            "estimates_window_s=[0.1,0.5]", "--no-plots"]  # fmt: skip
    code, _, err = run_main(args, capsys)
    assert code == 0, err
    (good,) = run_dirs(base)
    assert os.readlink(base / "latest") == good.name
    assert not (good / "plots").exists()  # --no-plots

    def fault(built, observers, hold_s=None, chunk_s=None):
        raise SimulationError("injected fault", 0.0, 0)

    with monkeypatch.context() as patch:
        patch.setattr(run_module, "_simulate", fault)
        code, _, err = run_main(args, capsys)
    assert code == 1 and "injected fault" in err
    failed = [d for d in run_dirs(base) if d != good]
    assert len(failed) == 1  # the failed run is kept, with status failed, but is not latest
    assert json.loads((failed[0] / "summary.json").read_text())["status"] == "failed"
    assert os.readlink(base / "latest") == good.name

    def interrupt(built, observers, hold_s=None, chunk_s=None):
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(run_module, "_simulate", interrupt)
        code, _, err = run_main(args, capsys)
    assert code == 130
    assert sorted(run_dirs(base)) == sorted([good, failed[0]])  # the interrupted run's directory is gone
    assert os.readlink(base / "latest") == good.name


def test_a_damaged_trace_leaves_the_run_out_of_the_plots_only(two_runs, tmp_path, capsys):
    work, _, _ = two_runs
    first, second = run_dirs(work / "runs" / "no_load_circle")
    damaged = tmp_path / "damaged"
    shutil.copytree(first, damaged)
    (damaged / "trace.parquet").write_bytes(b"not parquet")
    code, stdout, err = run_main(["compare", str(damaged), str(second), "--out", str(tmp_path / "c")], capsys)
    assert code == 0, err
    assert "Traceback" not in err and f"#1 ({damaged}): trace.parquet unreadable (" in err
    assert "| eps_c rms over window_s (um) | " in stdout
    assert sorted(p.name for p in (tmp_path / "c" / "plots").iterdir()) == sorted(FIGURES)
