"""A controller FMU that crashes, aborts, exits, hangs or leaks cannot take the twin down (docs/fmi.md, "When an FMU
misbehaves"; docs/hostile-input.md, "Controller FMUs that misbehave"): each is built from examples/fmu-pd/pd.c
(gcc, fmpy's FMI 2.0 headers) to misbehave in fmi2DoStep from t = 1 s of a 2 s run, and ``gantry-twin run`` in a
child process ends with exit 1 and the documented line, summary.json with ``status: failed`` and the trace up to
the last chunk before t = 1 s; no process and no temporary file is left. The endless one also stops within 2 s
of SIGINT (exit 130).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.fmi import fmu_controller

from .test_fmi_controller import GAINS, IMPORTED_FROM, _builder

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "hostile-input.md"
SECTION = "## Controller FMUs that misbehave"
#: pd.c's MISBEHAVE values, and when: t = 1 s, sample 5000 of the 2 s run; a chunk is 0.1 s, 500 samples.
KINDS = {"segfault": 1, "abort": 2, "exit": 3, "endless": 4, "leak": 5}
AT_S, AT_STEP, CHUNK = 1.0, 5000, 500
#: The endless one's call limit (--fmu-timeout), s, and the leak's memory limit (--fmu-memory), MiB: small, so
#: that the tests take little time and memory.
TIMEOUT_S, MEMORY_MIB = 1.0, 512
#: Each run ends within this, s; the endless one within its limit plus ENDLESS_ENDS_WITHIN_S.
ENDS_WITHIN_S, ENDLESS_ENDS_WITHIN_S = 15.0, 10.0

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not found: the test FMUs are built from C")


def documented() -> dict[str, str]:
    """case id -> the documented line (``...`` stands for the parts that vary, ``<out>`` for the run's directory)."""
    text = DOC.read_text(encoding="utf-8").split(SECTION, 1)[1].split("\n## ", 1)[0]
    return dict(re.findall(r"^\| `([^`]+)` \| .* \| `(.*)` \|$", text, flags=re.MULTILINE))


CASES = documented() if SECTION in DOC.read_text(encoding="utf-8") else {}


@pytest.fixture(scope="module")
def misbehaving(tmp_path_factory) -> dict[str, Path]:
    """Each kind's pd.fmu; the FMU's loop compiled (or loaded) here first, so that the runs below load it."""
    build = _builder().build_fmu
    root = tmp_path_factory.mktemp("misbehaving")
    fmus = {
        kind: build(root / kind, defines=(f"MISBEHAVE_AT_S={AT_S}", f"MISBEHAVE={value}"))
        for kind, value in KINDS.items()
    }
    simulate(Plant(), circle(), TimingLaw(2.0, "on_path"), fmu_controller(fmus["segfault"], parameters=GAINS), 0.01)
    return fmus


def _start(fmu: Path, where: Path, *flags: str) -> tuple[subprocess.Popen, Path]:
    """``gantry-twin run s.yaml --out out`` in a child process, its temporary directory ``where/tmp``, core dumps
    allowed (the worker forbids its own: a crash leaves no core of it in ``where``)."""
    (where / "tmp").mkdir()
    options = json.dumps({"fmu": str(fmu), "parameters": GAINS})
    (where / "s.yaml").write_text(f"duration_s: 2\ncontroller: {{name: fmu, options: {options}}}\n")
    env = {**os.environ, "TMPDIR": str(where / "tmp"), "PYTHONPATH": IMPORTED_FROM}
    command = [sys.executable, "-m", "gantry_twin", "run", "s.yaml", "--out", "out", "--no-plots", "--no-progress"]
    child = subprocess.Popen([*command, *flags], cwd=where, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True, preexec_fn=_cores_allowed)  # fmt: skip
    return child, where / "tmp"


def _cores_allowed() -> None:
    with contextlib.suppress(ValueError, OSError):
        hard = resource.getrlimit(resource.RLIMIT_CORE)[1]
        resource.setrlimit(resource.RLIMIT_CORE, (hard, hard))


def _core_limits(pid: int) -> list[str]:
    """The core size limits (soft hard) of the worker processes ``pid`` forked, from /proc."""
    limits = []
    for child in Path(f"/proc/{pid}/task/{pid}/children").read_text().split():
        for line in Path(f"/proc/{child}/limits").read_text().splitlines():
            if line.startswith("Max core file size"):
                limits.append(" ".join(line.split()[4:6]))
    return limits


def _left_behind(where: Path) -> list[str]:
    """Processes still running this test's scenario (the command or a worker it forked), by their command line."""
    found = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            try:
                line = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                cwd = os.readlink(proc / "cwd")
            except OSError:
                continue
            if "gantry_twin" in line and cwd == str(where):
                found.append(f"{proc.name}: {line}")
    return found


def _matches(documented_line: str, line: str, out: Path) -> bool:
    pattern = re.escape(documented_line.replace("<out>", str(out))).replace(re.escape("..."), ".+?")
    return re.fullmatch(pattern, line) is not None


class _Chunks:
    """An observer that keeps a copy of every chunk's positions, commands and logged values, as they come."""

    def __init__(self) -> None:
        self.q, self.u, self.logged = [], [], []

    def on_start(self, run, trace):
        pass

    def on_chunk(self, trace, start, stop):
        rows = trace.rows(start, stop)
        self.q.append(trace.q_m[rows].copy())
        self.u.append(trace.u_v[rows].copy())
        self.logged.append(trace.controller_state["fmu_u_x_v"][rows].copy())

    def on_end(self, trace):
        pass


def test_a_run_in_pieces_in_the_worker_is_the_run_in_process(misbehaving, tmp_path):
    """Held in pieces (the first recorded in shared memory, the others handed over chunk by chunk) with a logged
    variable: the observers see, chunk by chunk, what the same FMU run in this process gives, to the bit."""
    fmu = _builder().build_fmu(tmp_path / "pd")
    runs = []
    for isolated in (True, False):
        controller = fmu_controller(fmu, parameters=GAINS, log_variables=("u_x_v",))
        assert controller.isolation is not None
        if not isolated:
            controller.isolation = None
        chunks = _Chunks()
        trace = simulate(
            Plant(), circle(), TimingLaw(2.0, "on_path"), controller, 0.5, observers=[chunks], chunk_s=0.03, hold_s=0.2
        )
        runs.append((chunks, trace))
    (worker, last_w), (here, last_h) = runs
    assert len(worker.q) == len(here.q) >= 3 * 3  # three pieces of several chunks
    for got, want in ((worker.q, here.q), (worker.u, here.u), (worker.logged, here.logged)):
        assert np.array_equal(np.concatenate(got), np.concatenate(want))
    assert np.array_equal(np.concatenate(worker.logged), np.concatenate(worker.u)[:, 0])  # the FMU's u_x_v
    assert last_w.first == last_h.first > 0 and np.array_equal(last_w.q_m, last_h.q_m)


def test_every_misbehaviour_is_documented():
    assert set(CASES) == {f"fmu_{kind}" for kind in KINDS}


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_a_misbehaving_fmu_ends_as_a_failed_run_with_its_trace(kind, misbehaving, tmp_path):
    flags = {"endless": ("--fmu-timeout", str(TIMEOUT_S)), "leak": ("--fmu-memory", str(MEMORY_MIB))}.get(kind, ())
    child, tmp = _start(misbehaving[kind], tmp_path, *flags)
    try:
        _, err = child.communicate(timeout=TIMEOUT_S + ENDLESS_ENDS_WITHIN_S if kind == "endless" else ENDS_WITHIN_S)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert _matches(CASES[f"fmu_{kind}"], lines[0], Path("out")), lines[0]
    out = tmp_path / "out"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed"
    assert summary["failure"]["time_s"] == pytest.approx(AT_S, abs=0.25)  # the leak: when it passed the limit
    t_s = pq.read_table(out / "trace.parquet").column("t_s").to_numpy()
    assert t_s.size == summary["steps"]
    assert AT_STEP - CHUNK <= t_s.size <= AT_STEP  # the chunks before t = 1 s, none after it
    assert not np.isnan(pq.read_table(out / "trace.parquet").column("x_m").to_numpy()).any()
    assert sorted(p.name for p in out.iterdir()) == ["run_info.json", "scenario.yaml", "summary.json", "trace.parquet"]
    assert list(tmp.iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "s.yaml", "tmp"]  # no core of the worker
    assert _left_behind(tmp_path) == []


def _interrupt(child: subprocess.Popen, ready, settle_s: float) -> tuple[str, float]:
    """Wait (at most 120 s) until ``ready()``, then ``settle_s`` more, then SIGINT ``child``: its stderr and the
    seconds it took to end after the signal; the child is killed if it is still there."""
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and child.poll() is None and not ready():
            time.sleep(0.1)
        time.sleep(settle_s)
        assert child.poll() is None, child.communicate()[1]
        sent = time.monotonic()
        child.send_signal(signal.SIGINT)
        _, err = child.communicate(timeout=30)
        return err, time.monotonic() - sent
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()


def test_an_endless_call_stops_within_2_s_of_sigint(misbehaving, tmp_path):
    """At its default 10 s limit, the endless call is interrupted: exit 130 within 2 s, nothing left behind."""
    child, tmp = _start(misbehaving["endless"], tmp_path)

    core_limits: list[str] = []

    def ready() -> bool:  # the worker's trace reached t = 1 s
        parts = list((tmp_path / "out").glob(".trace.parquet.*.part")) if (tmp_path / "out").exists() else []
        if parts and list(tmp.glob("gantry-twin-worker-*/gantry-twin-fmu-*")):
            core_limits.extend(_core_limits(child.pid))
            return True
        return False

    err, took_s = _interrupt(child, ready, 1.5)  # 1.5 s: well into the endless call (t = 1 s comes in about 0.3 s)
    assert core_limits and all(limit == "0 0" for limit in core_limits), core_limits  # the worker dumps no core
    assert child.returncode == 130, err
    assert took_s < 2.0
    assert err.strip().splitlines() == ["gantry-twin: interrupted (SIGINT)"]
    assert list(tmp.iterdir()) == []
    assert not (tmp_path / "out").exists()  # a run stopped by a signal leaves nothing (docs/cli.md)
    assert _left_behind(tmp_path) == []


def test_an_endless_trial_start_stops_within_2_s_of_sigint(tmp_path):
    """An FMU whose fmi2Instantiate never returns: the trial start (in a worker) waits up to 60 s; SIGINT ends
    it within 2 s, exit 130, nothing left (docs/hostile-input.md, "Controller FMUs")."""
    fmu = _builder().build_fmu(tmp_path / "fmu", defines=("MISBEHAVE_ON_START=1", f"MISBEHAVE={KINDS['endless']}"))
    where = tmp_path / "run"
    where.mkdir()
    child, tmp = _start(fmu, where)

    def unpacked() -> bool:  # the trial start's worker unpacked the FMU
        return bool(list(tmp.glob("gantry-twin-worker-*/gantry-twin-fmu-*/binaries")))

    err, took_s = _interrupt(child, unpacked, 1.0)
    assert child.returncode == 130, err
    assert took_s < 2.0
    assert err.strip().splitlines() == ["gantry-twin: interrupted (SIGINT)"]
    assert list(tmp.iterdir()) == [] and not (where / "out").exists()
    assert _left_behind(where) == []


def test_the_limits_are_checked_before_the_run(misbehaving, tmp_path):
    """``--fmu-timeout 0`` and a memory limit below 64 MiB are refused in one line, exit 2, nothing run."""
    for flags, message in (
        (("--fmu-timeout", "0"), "argument --fmu-timeout: must be in [0.01, 86400] s, got 0"),
        (("--fmu-memory", "10"), "argument --fmu-memory: must be in [64, 1048576] MiB, got 10"),
    ):
        where = tmp_path / flags[0].strip("-")
        where.mkdir()
        child, _ = _start(misbehaving["segfault"], where, *flags)
        _, err = child.communicate(timeout=120)
        assert child.returncode == 2
        assert err.strip() == f"gantry-twin run: error: {message} (see gantry-twin run --help)"
        assert not (where / "out").exists()
