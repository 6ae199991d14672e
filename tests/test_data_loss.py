"""Nothing earlier lost, no stray temporary, no truncated file under a final name; network waits bounded; faults
of a sweep's points reported per point (docs/hostile-input.md, "Data loss, waits and faults").

The disk-full case is a child process under ``RLIMIT_FSIZE`` with SIGXFSZ ignored: every write past the limit
fails with EFBIG, as on a full disk it fails with ENOSPC. It needs no privilege (a tmpfs of its own would need
root and a mount namespace, which CI does not give) and hits only the child.
"""

from __future__ import annotations

import contextlib
import os
import resource
import signal
import socket
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from gantry_twin.sweep.engine import CONNECT_TIMEOUT_S, ClusterError, probe_scheduler

from .helpers import read_rrd
from .test_hostile_input import SWEEP, TIME_LIMIT_S, Case, Outcome, _make, run_children

#: A short run recorded with --save (its .rrd is some hundreds of KB; summary.json a few KB), no trace or plots.
SAVE_RUN = ["run", "--set", "outputs.trace=false", "--no-plots", "--save", "r.rrd"]
#: The disk-full child may write files of at most this many bytes (its summary.json fits, its recording does not).
FSIZE_LIMIT = 64 * 1024
#: A scheduler wait may end this much after the connect timeout (the sweep plans its points first), s.
WAIT_SLACK_S = 15.0
DEADLINE_S = 900  # a first run compiles the loop: minutes on a loaded machine


def _cli(cwd: Path, *argv: str, preexec=None, **popen) -> subprocess.Popen:  # noqa: ANN001
    return subprocess.Popen(
        [sys.executable, "-m", "gantry_twin.cli", *argv],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=preexec,
        **popen,
    )


def _finish(child: subprocess.Popen) -> tuple[str, str]:
    """Its output, once it ends (killed, and the test failed, if it has not within DEADLINE_S)."""
    try:
        return child.communicate(timeout=DEADLINE_S)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()


def _disk_full() -> None:
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG from write(), not a kill: what a full disk does
    resource.setrlimit(resource.RLIMIT_FSIZE, (FSIZE_LIMIT, FSIZE_LIMIT))


def _temporaries(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.endswith(".part"))


def _wait_for(condition, what: str, timeout_s: float = DEADLINE_S):  # noqa: ANN001
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        found = condition()
        if found:
            return found
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, bytes]:
    """A directory holding r.rrd, a complete recording of a 0.3 s run (the earlier result the cases must keep)."""
    cwd = tmp_path_factory.mktemp("save")
    child = _cli(cwd, *SAVE_RUN, "--set", "duration_s=0.3", "--out", "first")
    _, err = _finish(child)
    assert child.returncode == 0, err
    data = (cwd / "r.rrd").read_bytes()
    assert len(data) > FSIZE_LIMIT and read_rrd(cwd / "r.rrd")  # past the disk-full limit, and readable
    return cwd, data


@pytest.mark.exhaustive  # a --save of a real run under RLIMIT_FSIZE: ~60 s; run with -m exhaustive
def test_disk_full_during_save_exit_1_the_earlier_recording_kept_no_temporary(recorded):
    cwd, earlier = recorded
    child = _cli(cwd, *SAVE_RUN, "--set", "duration_s=0.3", "--out", "full", preexec=_disk_full)
    _, err = _finish(child)
    assert child.returncode == 1, err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err  # rerun's own lines about the failed write are not shown
    assert lines[0].startswith("gantry-twin: --save r.rrd: recording not written (") and "full/" in lines[0]
    assert (cwd / "r.rrd").read_bytes() == earlier  # the earlier recording, not a truncated one
    assert _temporaries(cwd) == []
    assert (cwd / "full" / "summary.json").is_file()  # the run itself is complete; only the recording failed


@pytest.mark.exhaustive  # a real --save killed mid-write: ~60 s; run with -m exhaustive
@pytest.mark.parametrize("how", ["SIGTERM", "SIGKILL"])
def test_a_signal_during_save_keeps_the_earlier_recording(recorded, how):
    """SIGTERM: exit 143 and the temporary removed. SIGKILL: the temporary stays (nothing can remove it), and the
    next --save into the same directory removes it. Either way r.rrd is the earlier, complete recording."""
    cwd, earlier = recorded
    child = _cli(cwd, *SAVE_RUN, "--set", "duration_s=60", "--realtime", "1", "--out", f"cut_{how}")
    try:
        part = _wait_for(lambda: [p for p in cwd.glob(".r.rrd.*.part") if p.stat().st_size > 0], "the recording")
        child.send_signal(signal.Signals[how])
        _, err = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
    assert (cwd / "r.rrd").read_bytes() == earlier
    if how == "SIGTERM":
        assert child.returncode == 128 + signal.SIGTERM, err
        assert err.strip().splitlines()[-1] == "gantry-twin: interrupted (SIGTERM)"
        assert _temporaries(cwd) == []
        return
    assert child.returncode == -signal.SIGKILL and _temporaries(cwd) == [part[0].name]
    again = _cli(cwd, *SAVE_RUN, "--set", "duration_s=0.3", "--out", "again")
    _, err = _finish(again)
    assert again.returncode == 0, err
    assert _temporaries(cwd) == []  # the killed run's temporary removed by the next --save here
    assert (cwd / "r.rrd").read_bytes() != earlier and read_rrd(cwd / "r.rrd")  # the new one, complete


def _dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_a_killed_sweeps_temporaries_are_removed_by_the_next_sweep_in_that_out(tmp_path):
    """results.parquet's, a figure's and a kept run's temporaries of a dead driver go; a live one's stay; the
    results are as they were (every point done: nothing runs, no cluster starts)."""
    import pyarrow.parquet as pq

    from gantry_twin.sweep import load_sweep, plan_sweep, run_sweep
    from gantry_twin.sweep.table import ResultsTable

    path = tmp_path / "w.yaml"
    path.write_text(SWEEP)
    plan = plan_sweep(load_sweep(path), str(path))
    out = tmp_path / "out"
    table = ResultsTable(plan, out / "results.parquet")
    for k, point in enumerate(plan.points):
        table.add(point, {"contour_rms_um": 1.0 + k, "status": "ok", "error": None, "wall_time_s": 0.5})
    rows = pq.read_table(out / "results.parquet").to_pylist()
    dead, alive = _dead_pid(), os.getpid()
    stale = [f".results.parquet.{dead}.a1b2.part", f".contour_rms_um.png.{dead}.x9.part"]
    kept = f".results.parquet.{alive}.c3d4.part"
    (out / "runs" / "k").mkdir(parents=True)
    for name in (*stale, kept):
        (out / name).write_bytes(b"cut short")
    (out / "runs" / "k" / f".summary.json.{dead}.q7.part").write_bytes(b"{")
    done = run_sweep(plan, out, resume=True)
    assert done.ran == 0 and done.done_before == len(plan.points)
    assert _temporaries(out) == [kept]
    assert _temporaries(out / "runs" / "k") == []
    assert pq.read_table(out / "results.parquet").to_pylist() == rows


# ---------------------------------------------------------------------------
# Bounded waits: --scheduler at an address that is not a Dask scheduler.


@contextlib.contextmanager
def _server(kind: str):
    """A TCP server on a free port of 127.0.0.1 that accepts and: ``silent`` says nothing; ``http`` is an HTTP
    server (it waits for a request); ``http_first`` sends an HTTP reply at once (once read by Dask as 3 EiB)."""
    listener = socket.create_server(("127.0.0.1", 0))
    held: list[socket.socket] = []
    stop = threading.Event()

    def serve() -> None:
        listener.settimeout(0.1)
        while not stop.is_set():
            try:
                conn, _ = listener.accept()
            except TimeoutError:
                continue
            held.append(conn)
            if kind == "http_first":
                conn.sendall(b"HTTP/1.0 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
            elif kind == "http":
                conn.settimeout(0.5)
                with contextlib.suppress(OSError):
                    if conn.recv(4096):
                        conn.sendall(b"HTTP/1.0 400 Bad Request\r\n\r\n")

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield listener.getsockname()[1]
    finally:
        stop.set()
        thread.join(5)
        for conn in held:
            conn.close()
        listener.close()


NOT_SCHEDULERS = ("silent", "http", "http_first")


@pytest.fixture(scope="module")
def not_schedulers(tmp_path_factory) -> dict[str, tuple[int, Outcome]]:
    """kind -> (port, outcome) of ``sweep --scheduler`` at each kind of :func:`_server`, each in its own child.

    The three children run at the same time, each against its own server: the two silent ones wait out the connect
    timeout together instead of one after the other. A child's wall time and CPU time are its own either way."""
    root = tmp_path_factory.mktemp("not_schedulers")
    with contextlib.ExitStack() as servers, ThreadPoolExecutor(len(NOT_SCHEDULERS)) as pool:
        runs = {}
        for kind in NOT_SCHEDULERS:
            port = servers.enter_context(_server(kind))
            case = Case(
                kind, {"w.yaml": SWEEP}, ("sweep", "w.yaml", "--out", "out", "--scheduler", f"127.0.0.1:{port}")
            )
            _make(root / kind, case.files)
            runs[kind] = (port, pool.submit(run_children, [case], root, "fork"))
        return {kind: (port, future.result()[kind]) for kind, (port, future) in runs.items()}


@pytest.mark.parametrize(
    "kind, answer",
    [
        ("silent", f"no Dask handshake within {CONNECT_TIMEOUT_S:g} s (accepted, then silent"),
        ("http", f"no Dask handshake within {CONNECT_TIMEOUT_S:g} s (accepted, then silent"),
        ("http_first", "answers, but not as a Dask scheduler (e.g. an HTTP server)"),
    ],
)
def test_scheduler_that_is_not_one_exit_2_within_the_connect_timeout(not_schedulers, kind, answer):
    """Once: still waiting after 300 s (silent), or a MemoryError for 3 EiB (an HTTP reply read as a length)."""
    port, o = not_schedulers[kind]
    assert o.code == 2, o
    lines = o.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in o.stderr, o.stderr
    assert lines[0].startswith(f"gantry-twin: error: --scheduler 127.0.0.1:{port}: {answer}"), lines[0]
    assert o.cpu_s < TIME_LIMIT_S  # waiting costs no CPU
    # Ended by the timeout (silent servers) or at once (an HTTP reply), never later; slack for the sweep's planning.
    assert o.child_wall_s < CONNECT_TIMEOUT_S + WAIT_SLACK_S, o.child_wall_s
    if kind != "http_first":  # a silent server is waited for, the whole timeout and no more
        assert o.child_wall_s >= CONNECT_TIMEOUT_S, o.child_wall_s
    assert o.written == []


def test_a_dask_scheduler_passes_the_probe():
    """The probe's own check can pass: a real scheduler's handshake is read as one (in-process, no workers)."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=0, processes=False, dashboard_address=":0") as cluster:
        probe_scheduler(cluster.scheduler_address, timeout_s=10)
    with _server("silent") as port, pytest.raises(ClusterError, match="no Dask handshake within 0.5 s"):
        probe_scheduler(f"tcp://127.0.0.1:{port}", timeout_s=0.5)


def _descendants(pid: int) -> list:
    import psutil

    found = []
    for p in psutil.Process(pid).children(recursive=True):
        with contextlib.suppress(psutil.Error):  # multiprocessing's resource tracker lives as long as we do
            if p.status() != psutil.STATUS_ZOMBIE and "resource_tracker" not in " ".join(p.cmdline()):
                found.append(p)
    return found


#: A bounded wait that is not bounded fails its test after this long instead of hanging it, s.
UNBOUNDED_AFTER_S = 90.0


def _sweep_in_process(tmp_path: Path, capsys, write_spec: bool = True) -> tuple[int, list[str], Path]:  # noqa: ANN001
    """``sweep`` of two points (w.yaml: SWEEP unless written) on one local worker, in a thread: the test fails if
    it is still waiting after UNBOUNDED_AFTER_S (with a timeout broken, it would wait for ever)."""
    from .helpers import run_main

    if write_spec:
        (tmp_path / "w.yaml").write_text(SWEEP)
    out = tmp_path / "out"
    answer: list = []
    argv = ["sweep", str(tmp_path / "w.yaml"), "--out", str(out), "--workers", "1"]
    thread = threading.Thread(target=lambda: answer.append(run_main(argv, capsys)), daemon=True)
    thread.start()
    thread.join(UNBOUNDED_AFTER_S)
    assert not thread.is_alive(), f"the sweep still waited after {UNBOUNDED_AFTER_S:g} s"
    code, _, err = answer[0]
    return code, err.strip().splitlines(), out


def test_a_local_worker_that_never_starts_ends_the_sweep_with_one_line(tmp_path, capsys, monkeypatch):
    """A LocalCluster's start is bounded (engine.CLUSTER_START_TIMEOUT_S, the nannies' death_timeout): a worker
    stuck at start (here a preload that sleeps) once kept a sweep waiting for ever. Exit 2, one line, no run."""
    import dask
    import distributed  # noqa: F401  its config section first: dask.config.set would otherwise remove it on exit

    from gantry_twin.sweep import engine

    (tmp_path / "stuck_preload.py").write_text("import time\ntime.sleep(3600)\n")
    monkeypatch.setattr(engine, "CLUSTER_START_TIMEOUT_S", 3.0)
    started = time.monotonic()
    with dask.config.set({"distributed.worker.preload": [str(tmp_path / "stuck_preload.py")]}):
        code, lines, out = _sweep_in_process(tmp_path, capsys)
    assert code == 2, lines
    assert len(lines) == 1 and "worker(s) did not start within 3 s" in lines[0], lines
    assert time.monotonic() - started < 3.0 + WAIT_SLACK_S
    assert not (out / "results.parquet").exists()
    assert not [p for p in _descendants(os.getpid()) if p.is_running()], "the stuck worker outlived the sweep"


def test_a_warm_up_that_never_ends_ends_the_sweep_with_one_line(tmp_path, capsys, monkeypatch):
    """The workers' warm-up (compile or load the loops) is bounded (engine.WARM_UP_TIMEOUT_S): a worker stuck
    there (here a warm-up that sleeps; in life a process holding the compile lock) once held the driver in
    gather() for ever. Sweep and tune share the engine's prepare_workers. Exit 2, one line, no run."""
    from gantry_twin.sweep import engine

    monkeypatch.setattr(engine, "WARM_UP_TIMEOUT_S", 2.0)
    monkeypatch.setattr(engine, "_warm_up_all", lambda *args: time.sleep(3600))  # pickled by value to the worker
    started = time.monotonic()
    code, lines, out = _sweep_in_process(tmp_path, capsys)
    assert code == 2, lines
    assert len(lines) == 1 and "did not compile or load the loop within 2 s" in lines[0], lines
    assert time.monotonic() - started < 2.0 + 2 * WAIT_SLACK_S  # a cluster's start, the wait, its close
    assert not (out / "results.parquet").exists()


# ---------------------------------------------------------------------------
# A fault in a point is that point's row, and the sweep's exit code says when all failed.


class _Exits:
    """A plug-in controller whose update() calls sys.exit() (or, made with ``at_init``, whose factory does)."""

    def __init__(self, at_init: bool = False) -> None:
        if at_init:
            sys.exit(0)

    def reset(self, context):  # noqa: ANN001
        pass

    def update(self, measurement, reference):  # noqa: ANN001
        if measurement.t_s > 0.01:
            sys.exit()
        return np.zeros(2)

    def state_for_logging(self):
        return {}


def test_an_unwritable_kernel_cache_fails_each_point_and_the_sweep(tmp_path, capsys, monkeypatch):
    """A numba cache the workers cannot write: NUMBA_CACHE_DIR under a regular file, so that making it fails
    with ENOTDIR even for root (chmod does not stop root). Each point's row says so, and the sweep exits 1,
    not 0. (numba itself falls back silently to a cache beside the sources: ``run`` with the same variable
    succeeds, checked by hand; it is the workers' compile lock that cannot be made.)"""
    (tmp_path / "a_file").write_text("")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "a_file" / "numba"))  # the workers inherit it
    (tmp_path / "w.yaml").write_text(SWEEP.replace("axes:", "set: {duration_s: 0.2}\naxes:"))
    code, lines, out = _sweep_in_process(tmp_path, capsys, write_spec=False)
    assert code == 1, lines
    assert lines[-1].startswith("gantry-twin: sweep failed: every point run failed"), lines
    rows = pq.read_table(out / "results.parquet").to_pylist()
    assert [r["status"] for r in rows] == ["failed", "failed"]
    assert all("cannot be made or locked (Not a directory); set NUMBA_CACHE_DIR" in r["error"] for r in rows), rows


def test_a_plugin_that_exits_in_a_point_gives_a_failed_row_not_an_exit():
    from gantry_twin.controllers import register, unregister
    from gantry_twin.scenario import load_scenario, shipped
    from gantry_twin.sweep.points import run_point

    register("exits_for_sweep", _Exits)
    try:
        sets = ["controller.name=exits_for_sweep", "duration_s=0.1", "window_s=[0,0.1]", "estimates_window_s=[0,0.1]"]
        result = run_point(load_scenario(shipped("no_load_circle"), sets).resolved(), "no_load_circle.yaml")
    finally:
        unregister("exits_for_sweep")
    assert result.row["status"] == "failed" and "SystemExit" in result.row["error"], result.row


def test_a_plugin_that_exits_or_raises_while_made_is_bad_input_not_exit_0(tmp_path, capsys, monkeypatch):
    """sys.exit(0) in a plug-in's factory once ended the program with exit 0; a plug-in module that raises at
    import, or is missing, once gave a traceback. Each is now one line naming controller.name, exit 2."""
    from gantry_twin.controllers import register, unregister

    from .helpers import run_main

    pkg = tmp_path / "plugins"
    pkg.mkdir()
    (pkg / "raises_at_import.py").write_text("raise RuntimeError('no licence server')\n")
    dist = pkg / "acme_faulty-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: acme-faulty\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(
        "[gantry_twin.controllers]\nraises_at_import = raises_at_import:C\nmissing_module = no_such_module:C\n"
    )
    monkeypatch.syspath_prepend(str(pkg))
    register("exits_when_made", lambda **_: _Exits(at_init=True))
    answers = {
        "exits_when_made": "controller 'exits_when_made' raised SystemExit: 0 while being made",
        "raises_at_import": "the plug-in of controller 'raises_at_import' cannot be imported (RuntimeError: no licence",
        "missing_module": "the plug-in of controller 'missing_module' cannot be imported (ModuleNotFoundError",
    }
    try:
        for name, answer in answers.items():
            out = tmp_path / f"out_{name}"
            code, stdout, err = run_main(["run", "--controller", name, "--out", str(out)], capsys)
            assert code == 2, (name, err)
            lines = err.strip().splitlines()
            assert len(lines) == 1 and "controller.name: " + answer in lines[0], lines
            assert not out.exists()
    finally:
        unregister("exits_when_made")
        sys.modules.pop("raises_at_import", None)
