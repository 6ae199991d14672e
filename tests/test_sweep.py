"""Sweeps on real multi-process Dask clusters (docs/sweeps.md): rows equal ``gantry-twin run``, faults, resume.

The clusters are real: a LocalCluster of worker processes started by the
``sweep`` command, and a ``dask scheduler`` with two ``dask worker``
processes started here on 127.0.0.1 and used through ``--scheduler``.
Points are 2-3 s of simulation. The fault tests (a worker killed, the driver
killed then resumed, SIGTERM) run the driver as a subprocess and are slow.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from gantry_twin.cli import app as cli
from gantry_twin.loop.trace import Trace
from gantry_twin.metrics import axial_rms_um, max_abs_command_v
from gantry_twin.sweep import load_sweep, plan_sweep
from gantry_twin.sweep.points import override

from .helpers import run_main
from .test_sweep_spec import MINIMAL

#: Ten DIARC points of 3 s (payload 0-9 kg): long enough to act while the sweep runs.
TEN_POINTS = """\
scenario: no_load_circle
set: {duration_s: 3, window_s: [0.5, 3], estimates_window_s: [1, 3]}
axes:
  - {field: payload.mass_kg, linspace: {start: 0, stop: 9, num: 10}}
"""
DEADLINE_S = 240.0


def rows_of(out: Path) -> list[dict]:
    return pq.read_table(out / "results.parquet").to_pylist()


def wait_for(condition, what: str, timeout_s: float = DEADLINE_S, every_s: float = 0.05):  # noqa: ANN001
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(every_s)
    raise AssertionError(f"timed out waiting for {what}")


def finished_rows(out: Path) -> int:
    try:
        return len(rows_of(out))
    except (FileNotFoundError, OSError):
        return 0


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict[tuple, dict]:
    """summary.json of ``gantry-twin run --set ...`` for each point of the minimal sweep, by its swept values.

    With --no-plots: the figures are not in summary.json (the same file to the byte with or without them) and were
    most of each run's time."""
    tmp = tmp_path_factory.mktemp("reference")
    path = tmp / "minimal.yaml"
    path.write_text(MINIMAL)
    spec = load_sweep(path)
    out = {}
    for point in plan_sweep(spec, str(path)).points:
        sets = [*(override(k, v) for k, v in spec.set.items()), *(override(k, v) for k, v in point.values.items())]
        run_dir = tmp / f"run{point.index}"
        argv = ["run", "no_load_circle", "--out", str(run_dir), "--no-progress", "--no-plots"]
        with contextlib.redirect_stdout(io.StringIO()):
            assert cli.main([*argv, *(a for s in sets for a in ("--set", s))]) == 0
        out[tuple(point.values.values())] = json.loads((run_dir / "summary.json").read_text())
    return out


def assert_rows_equal_runs(rows: list[dict], reference: dict[tuple, dict]) -> None:
    """Each row's metrics are those of ``gantry-twin run`` with its overrides, to the last bit."""
    assert len(rows) == len(reference) == 6
    for row in rows:
        summary = reference[(row["payload.mass_kg"], row["controller.name"])]
        assert row["status"] == "ok", row["error"]
        assert row["contour_rms_um"] == summary["contour_error_um"]["rms"]
        assert row["contour_max_um"] == summary["contour_error_um"]["max"]
        for name, e in summary["estimates"].items():
            assert row[f"estimate_{name}"] == e["estimate"] and row[f"true_{name}"] == e["true"]
            assert row[f"error_pct_{name}"] == e["error_pct"]


def test_local_cluster_rows_equal_gantry_twin_run(tmp_path, capsys, reference):
    path = tmp_path / "minimal.yaml"
    path.write_text(MINIMAL + "keep_runs: true\n")
    out = tmp_path / "out"
    code, stdout, err = run_main(["sweep", str(path), "--out", str(out), "--workers", "2"], capsys)
    assert code == 0, err
    assert "6 points: 0 done before, 6 run now (0 failed)" in stdout
    rows = rows_of(out)
    assert_rows_equal_runs(rows, reference)
    assert [r["point"] for r in rows] == list(range(6)) and len({r["key"] for r in rows}) == 6
    for row in rows:  # keep_runs: the run's own files, as gantry-twin run writes them
        kept = json.loads((out / "runs" / row["key"] / "summary.json").read_text())
        ran = reference[(row["payload.mass_kg"], row["controller.name"])]
        made = ("overrides", "controller_option")  # the command line's --set/--controller; a point's are in its row
        assert {k: v for k, v in kept.items() if k not in made} == {k: v for k, v in ran.items() if k not in made}
        assert kept["overrides"] == [] and kept["controller_option"] is None
        assert row["wall_time_s"] > 0 and row["alarms"] is None
    assert (out / "summary.md").read_text().count("| darc |") >= 3
    for name in ("contour_rms_um_vs_payload.mass_kg.png", "contour_rms_um_payload.mass_kg_x_controller.name.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"


# ---------------------------------------------------------------------------
# A dask scheduler and two dask workers on 127.0.0.1.


def _dask(*args: str, log: Path) -> subprocess.Popen:
    exe = Path(sys.executable).with_name("dask")
    with open(log, "wb") as fh:
        return subprocess.Popen([str(exe), *args], stdout=fh, stderr=subprocess.STDOUT, env=os.environ.copy())


@pytest.fixture(scope="module")
def scheduler(tmp_path_factory):
    """(address, [worker processes]): ``dask scheduler`` and two ``dask worker --nworkers 1 --nthreads 1``."""
    tmp = tmp_path_factory.mktemp("dask")
    info = tmp / "scheduler.json"
    host = ["--host", "127.0.0.1", "--no-dashboard"]
    procs = [_dask("scheduler", "--port", "0", "--scheduler-file", str(info), *host, log=tmp / "scheduler.log")]
    try:
        wait_for(lambda: info.is_file() and info.stat().st_size, "the scheduler file", 60)
        address = json.loads(info.read_text())["address"]
        for i in range(2):
            args = [
                "worker",
                "--scheduler-file",
                str(info),
                "--nworkers",
                "1",
                "--nthreads",
                "1",
                "--death-timeout",
                "60",
            ]
            procs.append(_dask(*args, *host, log=tmp / f"worker{i}.log"))
        from distributed import Client

        with Client(address, timeout=30) as client:
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        # The workers first, while their scheduler still answers (about 1 s); stopped together with it, a worker's
        # nanny often waited some 8 s for the lost scheduler before it ended.
        for group in (procs[1:], procs[:1]):
            for proc in group:
                proc.terminate()
            for proc in group:
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    proc.kill()


@pytest.mark.slow
def test_scheduler_and_two_workers_rows_equal_gantry_twin_run(tmp_path, capsys, reference, scheduler):
    path = tmp_path / "minimal.yaml"
    path.write_text(MINIMAL)
    out = tmp_path / "out"
    code, _, err = run_main(["sweep", str(path), "--out", str(out), "--scheduler", scheduler], capsys)
    assert code == 0, err
    assert_rows_equal_runs(rows_of(out), reference)


def _driver(path: Path, out: Path, *args: str) -> subprocess.Popen:
    argv = [sys.executable, "-m", "gantry_twin.cli", "sweep", str(path), "--out", str(out), "--no-progress", *args]
    return subprocess.Popen(
        argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=os.environ.copy(), start_new_session=True
    )


@pytest.mark.slow
def test_a_killed_worker_loses_no_point(tmp_path, scheduler):
    from distributed import Client

    path = tmp_path / "ten.yaml"
    path.write_text(TEN_POINTS)
    out = tmp_path / "out"
    driver = _driver(path, out, "--scheduler", scheduler)
    try:
        with Client(scheduler, timeout=30) as client:
            wait_for(lambda: finished_rows(out) >= 1, "the first point")
            # A worker in the middle of a point, killed by its PID (its nanny starts a new one).
            busy = wait_for(lambda: [w for w, keys in client.processing().items() if keys], "a busy worker")[0]
            pid = client.run(os.getpid, workers=[busy])[busy]
            os.kill(pid, signal.SIGKILL)
            stdout, stderr = driver.communicate(timeout=DEADLINE_S)
            assert driver.returncode == 0, stderr
            assert pid not in client.run(os.getpid).values()
    finally:
        if driver.poll() is None:
            driver.kill()
    rows = rows_of(out)
    assert sorted(r["point"] for r in rows) == list(range(10)) and len({r["key"] for r in rows}) == 10
    assert all(r["status"] == "ok" for r in rows), [r["error"] for r in rows]
    assert "10 run now (0 failed)" in stdout


def _descendants(pid: int) -> list:
    import psutil

    return psutil.Process(pid).children(recursive=True)


def _kill_the_driver(tmp: Path) -> tuple[Path, Path, list]:
    """A sweep of TEN_POINTS on 2 local workers, its driver SIGKILLed after three points: (spec, out, the driver's
    processes still alive 30 s after it died)."""
    import psutil

    path = tmp / "ten.yaml"
    path.write_text(TEN_POINTS)
    out = tmp / "out"
    driver = _driver(path, out, "--workers", "2")
    children: list = []
    try:
        wait_for(lambda: finished_rows(out) >= 3, "three points")
        children = _descendants(driver.pid)
        os.kill(driver.pid, signal.SIGKILL)
        driver.wait(timeout=30)
        _, alive = psutil.wait_procs(children, timeout=30)
    finally:
        for proc in [driver, *children]:  # only the processes this test started
            with contextlib.suppress(Exception):
                proc.kill()
    return path, out, alive


def _signal_the_driver(tmp: Path, how: str) -> tuple[Path, int, str, list]:
    """A sweep of TEN_POINTS on 2 local workers, stopped by ``how`` after two points: (out, exit code, stderr, the
    cluster's processes still alive 15 s after the driver ended)."""
    import psutil

    path = tmp / "ten.yaml"
    path.write_text(TEN_POINTS)
    out = tmp / "out"
    driver = _driver(path, out, "--workers", "2")  # in a session of its own, like a shell's job
    try:
        wait_for(lambda: finished_rows(out) >= 2, "two points")
        children = _descendants(driver.pid)
        if how == "sigterm_to_the_driver":
            driver.send_signal(signal.SIGTERM)
        else:  # a terminal's Ctrl-C reaches the driver and its worker processes at once
            os.killpg(driver.pid, signal.SIGINT)
        _, stderr = driver.communicate(timeout=60)
    finally:
        if driver.poll() is None:
            driver.kill()
    _, alive = psutil.wait_procs(children, timeout=15)  # the cluster's processes end with the driver
    return out, driver.returncode, stderr, alive


@pytest.fixture(scope="module")
def stopped_drivers(tmp_path_factory):
    """The three sweeps whose driver is stopped mid-way (killed; SIGTERM; Ctrl-C), started at once, each a driver
    and local cluster of its own in a directory of its own: their start-ups and waits overlap instead of adding up.
    name -> a future of what :func:`_kill_the_driver` or :func:`_signal_the_driver` returns (its error, if any,
    raised in the test that reads it). Each stops its own processes, failed or not, before the fixture returns."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(3) as pool:
        return {
            "killed": pool.submit(_kill_the_driver, tmp_path_factory.mktemp("killed")),
            **{
                how: pool.submit(_signal_the_driver, tmp_path_factory.mktemp(how), how)
                for how in ("sigterm_to_the_driver", "ctrl_c_to_the_process_group")
            },
        }


@pytest.mark.slow
def test_killed_driver_then_resume_runs_only_the_missing_points(stopped_drivers, capsys):
    path, out, alive = stopped_drivers["killed"].result()
    assert not alive, f"worker processes outlived the killed driver: {alive}"
    before = {r["key"]: r for r in rows_of(out)}
    assert 3 <= len(before) < 10, "the driver was killed too late to leave points missing"
    code, stdout, err = run_main(["sweep", str(path), "--out", str(out), "--workers", "2", "--resume"], capsys)
    assert code == 0, err
    after = {r["key"]: r for r in rows_of(out)}
    assert len(after) == 10 and sorted(r["point"] for r in after.values()) == list(range(10))
    assert all(after[key] == row for key, row in before.items()), "a point finished before the kill ran again"
    ran = [key for key in after if key not in before]
    assert len(ran) == 10 - len(before)
    assert f"{len(before)} done before, {len(ran)} run now (0 failed)" in stdout


@pytest.mark.slow
@pytest.mark.parametrize("how", ["sigterm_to_the_driver", "ctrl_c_to_the_process_group"])
def test_signals_stop_the_cluster_and_leave_a_valid_table(stopped_drivers, how):
    out, returncode, stderr, alive = stopped_drivers[how].result()
    name = "SIGTERM" if how == "sigterm_to_the_driver" else "SIGINT"
    assert returncode == 128 + signal.Signals[name].value, stderr  # as for run: 143 SIGTERM, 130 Ctrl-C
    assert stderr.strip().splitlines()[-1] == f"gantry-twin: interrupted ({name})"
    assert not alive, [" ".join(p.cmdline()) for p in alive]
    rows = rows_of(out)
    assert 2 <= len(rows) < 10 and all(r["status"] == "ok" for r in rows)
    assert not list(out.glob(".*.part"))
    assert (out / "summary.md").is_file()


# ---------------------------------------------------------------------------
# The engine's pieces.


def test_compile_lock_holds_across_processes(tmp_path):
    """Two processes take the kernel-cache lock in turn: their times inside never overlap."""
    code = (
        "import sys, time\n"
        "from gantry_twin.sweep.engine import compile_lock\n"
        "with compile_lock():\n"
        "    t0 = time.time(); time.sleep(0.5); t1 = time.time()\n"
        "print(t0, t1)\n"
    )
    procs = [
        subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=os.environ.copy())
        for _ in range(3)
    ]
    spans = sorted(tuple(map(float, p.communicate(timeout=60)[0].split())) for p in procs)
    assert all(p.returncode == 0 for p in procs)
    assert all(a[1] <= b[0] for a, b in zip(spans, spans[1:], strict=False)), spans


def test_a_run_that_raises_gives_a_failed_row():
    from gantry_twin.controllers import register, unregister
    from gantry_twin.scenario import load_scenario, shipped
    from gantry_twin.sweep.points import run_point

    class Broken:
        def reset(self, context):  # noqa: ANN001
            pass

        def update(self, measurement, reference):  # noqa: ANN001
            return np.array([np.nan, 0.0])

        def state_for_logging(self):
            return {}

    register("broken_for_sweep", Broken)
    try:
        sets = ["controller.name=broken_for_sweep", "duration_s=0.1", "window_s=[0,0.1]", "estimates_window_s=[0,0.1]"]
        scenario = load_scenario(shipped("no_load_circle"), sets)
        result = run_point(scenario.resolved(), "no_load_circle.yaml")
    finally:
        unregister("broken_for_sweep")
    assert result.row["status"] == "failed"
    assert result.row["error"].startswith("SimulationError: controller returned")
    assert "contour_rms_um" not in result.row


def test_axial_and_command_metrics_against_direct_computation():
    rng = np.random.default_rng(5)
    n = 1000
    t = np.arange(n) * 2e-4
    e = rng.normal(0, 1e-6, (n, 2))
    u = rng.uniform(-12, 12, (n, 2))
    u_max = np.array([10.0, 8.0])
    clipped = np.clip(u, -u_max, u_max)
    nan = np.full((n, 2), np.nan)
    trace = Trace(t, nan, nan, nan, e, t, t, clipped, nan, np.zeros(8), filled=n)
    window = (0.05, 0.15)
    inside = (t >= 0.05) & (t < 0.15)
    rms = axial_rms_um(trace, window)
    for axis in range(2):
        assert rms[axis] == pytest.approx(np.sqrt(np.mean((e[inside, axis] * 1e6) ** 2)))
    largest = max_abs_command_v(trace)
    for axis in range(2):
        assert largest[axis] == u_max[axis] and np.sum(np.abs(u[:, axis]) >= u_max[axis]) > 0


def test_resume_keeps_ok_rows_of_this_sweep_and_reruns_failed_ones_and_refuses_a_changed_sweep(tmp_path):
    from gantry_twin.scenario import ScenarioError
    from gantry_twin.sweep.table import ResultsTable

    path = tmp_path / "minimal.yaml"
    path.write_text(MINIMAL)
    plan = plan_sweep(load_sweep(path), str(path))
    first = ResultsTable(plan, tmp_path / "results.parquet")
    first.add(plan.points[0], {"contour_rms_um": 1.0, "status": "ok", "error": None, "wall_time_s": 0.5})
    first.add(plan.points[1], {"status": "failed", "error": "SimulationError: x", "wall_time_s": 0.1})
    first.add(plan.points[4], {"contour_rms_um": 2.0, "status": "ok", "error": None, "wall_time_s": 0.5})
    resumed = ResultsTable(plan, tmp_path / "results.parquet")
    assert resumed.load() == 2
    assert [resumed.done(p) for p in plan.points] == [True, False, False, False, True, False]
    assert resumed.rows[plan.points[1].key]["status"] == "failed"  # kept until it runs again
    # The same sweep with one payload value changed is another plan: its results are not taken.
    path.write_text(MINIMAL.replace("[0, 2.5, 5]", "[0, 2.5, 6]"))
    changed = plan_sweep(load_sweep(path), str(path))
    with pytest.raises(ScenarioError, match="holds the results of another sweep"):
        ResultsTable(changed, tmp_path / "results.parquet").load()
    assert [r["point"] for r in rows_of(tmp_path)] == [0, 1, 4]


def test_compile_lock_is_reentrant_in_a_thread_and_exclusive_across_threads():
    """``gantry-twin compile`` holds the lock while its short run compiles under it again: the inner take must not
    wait on the outer (once a deadlock: a second flock of the same process blocks as another process's would).
    Another thread still waits for it."""
    import threading

    from gantry_twin.sweep.engine import compile_lock

    order = []
    with compile_lock():
        with compile_lock():  # returns at once (a deadlock otherwise: the test would hang)
            order.append("inner")

        def other():
            with compile_lock():
                order.append("other")

        thread = threading.Thread(target=other)
        thread.start()
        thread.join(0.5)
        assert thread.is_alive() and order == ["inner"]  # waits while this thread holds it
        order.append("outer done")
    thread.join(30)
    assert order == ["inner", "outer done", "other"]
