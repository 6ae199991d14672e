"""Running and writing a scenario (gantry_twin.run): the output contract, faults that keep their evidence, and
runs held in pieces that write what a whole run writes."""

from __future__ import annotations

import json
import os
import re
import sys
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np
import pyarrow.parquet as pq
import pytest

from gantry_twin import run as run_module
from gantry_twin.cli import app as cli
from gantry_twin.controllers import PD, register, unregister
from gantry_twin.controllers.base import CompiledStep
from gantry_twin.controllers.pd import PDParams, pd_command
from gantry_twin.loop.simulate import compiled_available
from gantry_twin.outputs.summary import summary_json
from gantry_twin.outputs.tracefile import trace_table
from gantry_twin.run import RunWriter, execute, run_and_write, trace_size
from gantry_twin.scenario import build, load_scenario, shipped

from .helpers import run_main

#: Short runs: 0.3 s of simulation (1500 samples) with windows inside it.
OVERRIDES = ["duration_s=0.3", "window_s=[0.05, 0.3]", "estimates_window_s=[0.1, 0.3]"]
SHORT = [word for override in OVERRIDES for word in ("--set", override)]
TS = 2e-4
FAULT_STEP = 1000  # t = 0.2 s


def one_line(err: str) -> str:
    """The one line on stderr (the compile notice aside)."""
    assert "Traceback" not in err
    lines = [line for line in err.strip().splitlines() if "compiling the 0.2 ms loop" not in line]
    assert len(lines) == 1, err
    return lines[0]


# ---------------------------------------------------------------------------------------------
# One directory, one complete run; written only where it can be, checked before the run.


def test_a_run_without_trace_removes_the_trace_of_an_earlier_run(tmp_path, capsys):
    out = tmp_path / "out"
    args = ["run", "no_load_circle", *SHORT, "--out", str(out)]
    assert run_main(args, capsys)[0] == 0
    assert (out / "trace.parquet").exists()
    code, stdout, err = run_main([*args, "--set", "outputs.trace=false"], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["run_info.json", "scenario.yaml", "summary.json"]
    listed = stdout.strip().splitlines()[-1]
    assert listed == f"results in {out}/ (summary.json, scenario.yaml, run_info.json)"


def test_an_output_directory_that_cannot_be_written_is_bad_input_found_before_the_run(tmp_path, capsys, monkeypatch):
    def never(*args, **kwargs):
        raise AssertionError("simulated although the output directory cannot be written")

    monkeypatch.setattr(run_module, "simulate", never)
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory\n")
    cases = [blocker / "out"]  # a regular file where a directory should be made
    if os.geteuid() != 0:  # permissions do not stop root
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        cases.append(locked)
    for out in cases:
        code, stdout, err = run_main(["run", "no_load_circle", *SHORT, "--out", str(out)], capsys)
        assert code == 2, err
        line = one_line(err)
        assert f"--out {out}" in line and "cannot write there" in line
        assert stdout == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["a_file"] + (["locked"] if len(cases) > 1 else []))


def test_an_interrupted_run_leaves_the_earlier_run_whole_and_no_temporary_file(tmp_path, monkeypatch):
    out = tmp_path / "out"
    built = build(load_scenario(shipped("no_load_circle"), OVERRIDES))
    run_and_write(out, built)
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    class Interrupt:
        def on_start(self, run, trace):  # noqa: ANN001, ANN201
            pass

        def on_chunk(self, trace, start, stop):  # noqa: ANN001, ANN201
            if stop >= 1000:
                raise KeyboardInterrupt

        def on_end(self, trace):  # noqa: ANN001, ANN201
            pass

    fresh = tmp_path / "fresh" / "deeper"
    for where in (out, fresh):
        built = build(load_scenario(shipped("no_load_circle"), OVERRIDES))
        with pytest.raises(KeyboardInterrupt):
            run_and_write(where, built, [Interrupt()])
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # the directories it made are gone


# ---------------------------------------------------------------------------------------------
# A fault at t = 0.2 s keeps the trace up to it, and says where.


@dataclass
class FaultyPD(PD):
    """PD whose update() returns NaN (mode "nan") or raises (mode "raise") from sample FAULT_STEP on (Python loop)."""

    mode: str = "nan"

    def update(self, measurement, reference):  # noqa: ANN001, ANN201
        if measurement.t_s >= FAULT_STEP * TS - 1e-9:
            if self.mode == "raise":
                raise ValueError("plug-in fault")
            if self.mode == "exit":
                sys.exit()  # SystemExit(None): a plug-in that "stops the program"
            return np.array([np.nan, 0.0])
        return super().update(measurement, reference)


class FaultParams(NamedTuple):
    pd: PDParams
    fault_step: float
    raises: float


class Samples(NamedTuple):
    done: np.ndarray  # (1,)


@numba.njit
def faulty_step(params, state, t_s, q_m, dq_m_s, ref, u_v):
    pd_command(params.pd, (), t_s, q_m, dq_m_s, ref, u_v)
    if state.done[0] >= params.fault_step:
        if params.raises:
            raise ValueError("plug-in fault")
        u_v[0] = np.nan
    state.done[0] += 1.0


@numba.njit
def faulty_log(params, state, out):
    out[0] = state.done[0]


class CompiledFaultyPD(PD):
    """The same fault in a compiled step (runs in the compiled loop)."""

    compiled = CompiledStep(faulty_step, faulty_log, (("samples_done", ()),))

    def __init__(self, mode: str = "nan") -> None:
        super().__init__()
        self.mode = mode
        self.done = np.zeros(1)

    def kernel_arguments(self):  # noqa: ANN201
        pd, _ = super().kernel_arguments()
        return FaultParams(pd, float(FAULT_STEP), float(self.mode == "raise")), Samples(self.done)

    def reset(self, context):  # noqa: ANN001, ANN201
        super().reset(context)
        self.done[:] = 0.0

    def update(self, measurement, reference):  # noqa: ANN001, ANN201
        raise AssertionError("the compiled loop runs this controller")

    def state_for_logging(self):  # noqa: ANN201
        return {"samples_done": self.done.copy()}


@pytest.fixture
def faulty_controllers():
    register("faulty_py", FaultyPD)
    register("faulty_compiled", CompiledFaultyPD)
    yield
    unregister("faulty_py")
    unregister("faulty_compiled")


def check_evidence(out, code, err, mode):  # noqa: ANN001, ANN201
    """A run stopped at t = 0.2 s: exit 1, one line naming the time, the trace of the 1000 samples before it,
    summary.json with status failed."""
    assert code == 1, err
    line = one_line(err)
    assert "run failed" in line and "t = 0.2000 s (step 1000)" in line and str(out) in line, line
    raised = "the controller raised ValueError at t = 0.2000 s (step 1000): plug-in fault" in line
    returned = re.search(r"controller returned array\(\[\s*nan,\s*[-0-9.e]+\]\) at t = 0\.2000 s \(step 1000\)", line)
    assert raised == (mode == "raise") and bool(returned) == (mode == "nan"), line
    table = pq.read_table(out / "trace.parquet")
    assert table.num_rows == FAULT_STEP
    np.testing.assert_array_equal(table.column("t_s").to_numpy(), np.arange(FAULT_STEP) * TS)
    for name in table.column_names:
        assert np.isfinite(table.column(name).to_numpy()).all(), name
    data = json.loads((out / "summary.json").read_text())
    assert data["status"] == "failed" and data["steps"] == FAULT_STEP
    assert data["failure"]["step"] == FAULT_STEP and data["failure"]["time_s"] == pytest.approx(0.2, abs=1e-12)
    assert "t = 0.2000 s (step 1000)" in data["failure"]["error"]
    assert "contour_error_um" not in data  # a run that stopped early is not judged
    assert (out / "scenario.yaml").exists() and (out / "run_info.json").exists()
    return table


def test_a_plugin_that_calls_sys_exit_is_a_failed_run_not_exit_0(tmp_path, capsys, faulty_controllers):
    """sys.exit() in update(): the run stops as a failed run (exit 1, summary.json status failed, the trace kept)."""
    out = tmp_path / "out"
    args = ["run", "no_load_circle", *SHORT, "--controller", "faulty_py", "--set", "controller.options.mode=exit"]
    code, stdout, err = run_main([*args, "--out", str(out)], capsys)
    assert code == 1 and stdout == "", err
    assert "the controller raised SystemExit at t = 0.2000 s (step 1000)" in one_line(err)
    data = json.loads((out / "summary.json").read_text())
    assert data["status"] == "failed" and data["steps"] == FAULT_STEP and "SystemExit" in data["failure"]["error"]
    assert pq.read_table(out / "trace.parquet").num_rows == FAULT_STEP


@pytest.mark.parametrize("mode", ["nan", "raise"])
def test_a_python_plugin_fault_keeps_the_trace_up_to_it(tmp_path, capsys, faulty_controllers, mode):
    out = tmp_path / "out"
    args = ["run", "no_load_circle", *SHORT, "--controller", "faulty_py", "--set", f"controller.options.mode={mode}"]
    code, stdout, err = run_main([*args, "--out", str(out)], capsys)
    assert stdout == ""
    check_evidence(out, code, err, mode)


@pytest.mark.slow  # compiles a chunk kernel for the plug-in's step (once per machine)
@pytest.mark.skipif(not compiled_available(), reason="MuJoCo's library not found")
@pytest.mark.parametrize("mode", ["nan", "raise"])
def test_a_compiled_plugin_fault_keeps_the_trace_up_to_it(tmp_path, capsys, faulty_controllers, mode):
    out = tmp_path / "out"
    args = ["run", "no_load_circle", *SHORT, "--controller", "faulty_compiled"]
    code, _, err = run_main([*args, "--set", f"controller.options.mode={mode}", "--out", str(out)], capsys)
    table = check_evidence(out, code, err, mode)
    np.testing.assert_array_equal(table.column("samples_done").to_numpy(), np.arange(1, FAULT_STEP + 1))


def test_a_fault_in_a_run_held_in_pieces_keeps_every_piece_before_it(tmp_path, faulty_controllers):
    """The fault at the first sample of the third piece of 0.1 s: the file holds the two pieces before it."""
    out = tmp_path / "out"
    overrides = OVERRIDES + ["controller.name=faulty_py"]
    outcome = run_and_write(out, build(load_scenario(shipped("no_load_circle"), overrides)), hold_s=0.1)
    assert outcome.failed and outcome.error is not None and outcome.error.step == FAULT_STEP
    assert pq.ParquetFile(out / "trace.parquet").metadata.num_row_groups == 2
    assert pq.read_table(out / "trace.parquet").num_rows == FAULT_STEP


def test_a_good_run_says_status_ok(tmp_path):
    built = build(load_scenario(shipped("no_load_circle"), OVERRIDES))
    assert run_and_write(tmp_path / "out", built).summary.status == "ok"


# ---------------------------------------------------------------------------------------------
# A run held in pieces writes what a whole run writes; large traces are announced.


@pytest.mark.parametrize("stride", [1, 7])
def test_a_run_held_in_pieces_writes_what_a_whole_run_writes(tmp_path, stride):
    """Pieces of 0.3 s of a 2 s run (the windows, the plant change, the stride and the tangent angle's wrap at
    1.57 s across their seams): the same Parquet table and byte-identical summary.json as the whole trace."""
    overrides = [
        "duration_s=2.0",
        "window_s=[0.1, 1.9]",
        "estimates_window_s=[0.25, 1.95]",
        "changes={payload_change: [{time_s: 0.5, mass_kg: 3.0}]}",
        "monitor={enable: true, baseline_window_s: [0.2, 0.5]}",
        f"outputs.trace_stride={stride}",
    ]
    scenario = load_scenario(shipped("no_load_circle"), overrides)
    whole_run = build(scenario)
    whole = execute(whole_run)
    expected = trace_table(whole, stride)
    expected_summary = run_module.summarise(whole_run, whole)  # the whole trace, in one chunk

    built = build(scenario)
    outcome = run_and_write(tmp_path / "out", built, hold_s=0.3)
    written = pq.ParquetFile(tmp_path / "out" / "trace.parquet")
    assert written.metadata.num_row_groups == 7
    table = written.read()
    assert table.column_names == expected.column_names and "true_theta_M1" in table.column_names
    assert table.equals(expected)
    assert table.schema.metadata[b"true_theta"] == expected.schema.metadata[b"true_theta"]
    assert summary_json(outcome.summary) == summary_json(expected_summary)
    assert (tmp_path / "out" / "summary.json").read_text() == summary_json(expected_summary)
    assert os.path.getsize(tmp_path / "out" / "trace.parquet") <= 1.05 * trace_size(built).bytes


def test_a_trace_over_1_gb_is_announced_with_the_stride_that_fits(capsys):
    def note(*overrides: str) -> str:
        cli._announce_large_trace(build(load_scenario(shipped("no_load_circle"), list(overrides))))
        return capsys.readouterr().err

    assert note("duration_s=60") == ""
    line = one_line(note("duration_s=3600"))
    # 7 float64 columns (time, positions) and 27 float32 ones (DIARC): 164 bytes a row before compression.
    assert "up to 3.0 GB (18000000 samples x 34 columns, before compression)" in line
    assert "--set outputs.trace_stride=3" in line and "(up to 0.98 GB)" in line and "outputs.trace=false" in line
    assert note("duration_s=3600", "outputs.trace_stride=3") == ""
    assert note("duration_s=3600", "outputs.trace=false") == ""


def test_the_writer_checks_before_it_writes(tmp_path):
    """RunWriter made and discarded: nothing stays (the check of the directory is a temporary file)."""
    for trace in ("true", "false"):
        built = build(load_scenario(shipped("no_load_circle"), [*OVERRIDES, f"outputs.trace={trace}"]))
        with RunWriter(tmp_path / "new", built) as writer:
            assert (tmp_path / "new").is_dir()
            writer.discard()
        assert list(tmp_path.iterdir()) == []


def test_a_sigkilled_runs_temporaries_are_removed_by_the_next_run_in_its_directory(tmp_path, capsys):
    """SIGKILL leaves the trace's ``.trace.parquet.<pid>.*.part``; the next run into the same --out removes it
    (its process is gone) and leaves a live process's temporary and other files alone."""
    import signal
    import subprocess
    import time
    from pathlib import Path

    out = tmp_path / "out"
    src = Path(__file__).resolve().parents[1] / "src"
    env = {**os.environ, "PYTHONPATH": str(src)}
    command = [sys.executable, "-m", "gantry_twin.cli", "run", "--set", "duration_s=60", "--no-progress", "--out=out"]
    child = subprocess.Popen(command, cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120.0
        while not (out.is_dir() and list(out.glob(".trace.parquet.*.part"))):
            assert child.poll() is None and time.monotonic() < deadline, "no trace temporary appeared"
            time.sleep(0.05)
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
    finally:
        if child.poll() is None:
            child.kill()
    (stale,) = out.glob(".trace.parquet.*.part")
    assert stale.name.startswith(f".trace.parquet.{child.pid}.")
    live = out / f".trace.parquet.{os.getpid()}.abc123.part"  # this test's process is alive
    live.write_bytes(b"in use")
    (out / "notes.part").write_text("mine\n")
    code, _, err = run_main(["run", "no_load_circle", *SHORT, "--out", str(out), "--no-progress"], capsys)
    assert code == 0, err
    assert not stale.exists() and live.exists() and (out / "notes.part").exists()


def test_the_run_time_leaves_the_compile_out_and_run_info_gives_it(tmp_path):
    """A compile notice times the compile (run start to first chunk); 'simulated in N s' and run_info.json's
    wall_time_s are the rest, and run_info.json's compile_s is the compile."""
    import io
    import time

    from gantry_twin.loop.compiling import CompileNotice

    class SlowStart:  # stands for a compile: it holds the run between its start and its first chunk
        def on_start(self, run, trace):
            time.sleep(0.5)

        def on_chunk(self, trace, start, stop): ...

        def on_end(self, trace): ...

    built = build(load_scenario(shipped("no_load_circle"), OVERRIDES, "pd"))
    notice = CompileNotice("gantry-twin", io.StringIO())
    started = time.perf_counter()
    with RunWriter(tmp_path / "run", built) as writer:
        outcome = writer.run([notice, SlowStart()])
    elapsed_s = time.perf_counter() - started
    info = json.loads((tmp_path / "run" / "run_info.json").read_text())
    assert info["compile_s"] == notice.compile_s >= 0.5
    assert info["wall_time_s"] == outcome.wall_time_s <= elapsed_s - 0.5
    with RunWriter(tmp_path / "cached", built) as writer:  # nothing compiles: no compile_s
        writer.run()
    assert json.loads((tmp_path / "cached" / "run_info.json").read_text())["compile_s"] == 0.0


def test_run_scenario_times_a_compile_as_gantry_twin_run_does(tmp_path, monkeypatch):
    """run_info.json of a run written from Python: compile_s is the compile, wall_time_s the rest."""
    import time

    from gantry_twin import run_scenario
    from gantry_twin.loop import compiling

    def slow_start(self, run, trace):  # stands for a compile, between the run's start and its first chunk
        original(self, run, trace)
        time.sleep(0.5)

    original = compiling.CompileTimer.on_start
    monkeypatch.setattr(compiling.CompileTimer, "on_start", slow_start)
    monkeypatch.setattr(compiling, "loop_needs_compiling", lambda controller: True)
    started = time.perf_counter()
    run_scenario("no_load_circle", OVERRIDES, "pd", out=tmp_path / "run")
    elapsed_s = time.perf_counter() - started
    info = json.loads((tmp_path / "run" / "run_info.json").read_text())
    assert info["compile_s"] >= 0.5 and info["wall_time_s"] <= elapsed_s - 0.5
    monkeypatch.setattr(compiling, "loop_needs_compiling", lambda controller: False)
    run_scenario("no_load_circle", OVERRIDES, "pd", out=tmp_path / "cached")
    assert json.loads((tmp_path / "cached" / "run_info.json").read_text())["compile_s"] == 0.0


def test_compile_of_a_plug_in_whose_short_run_fails_is_exit_1_one_line(capsys, faulty_controllers, monkeypatch):
    import importlib

    simulate_module = importlib.import_module("gantry_twin.loop.simulate")  # the package's ``simulate`` is the function
    monkeypatch.setattr(simulate_module, "loop_needs_compiling", lambda controller: True)  # cached or not
    code, stdout, err = run_main(["compile", "--controller", "faulty_compiled"], capsys)
    line = one_line(err.split("\n", 1)[1] if err.startswith("gantry-twin (faulty_compiled): compiling") else err)
    assert code == 1 and "compiled:" not in stdout
    assert line.startswith("gantry-twin: faulty_compiled: compiling its loop with a short run failed: SimulationError:")
