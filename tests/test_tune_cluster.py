"""A tune on loopback clusters: a worker killed by its PID mid-trial and the study still completes; the driver
killed and ``--resume`` runs only the trials that remain."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from .helpers import run_main
from .test_sweep import scheduler  # noqa: F401 -- the fixture: a dask scheduler and two workers on 127.0.0.1

DEADLINE_S = 600.0
TRIALS = 8

SPEC = """\
set: {controller.name: pd, controller.options: {kp_v_m: [10000, 10000], kd_v_s_m: [100, 100]}, duration_s: 1.0,
      plant.model: paper}
scenarios: [{scenario: no_load_circle}]
ensemble: [{name: light, set: {plant.model: paper}}, {name: heavy, set: {plant.model: paper, payload.mass_kg: 5}}]
design:
  - {field: controller.options.kp_v_m.0, low: 1000, high: 100000, log: true, name: kp_x}
  - {field: controller.options.kd_v_s_m.0, low: 10, high: 1000, log: true, name: kd_x}
goals:
  - {metric: contour_rms_um, limit: 1, kind: soft}
  - {metric: saturated_fraction, limit: 0}
optimiser: {trials: 8, startup_trials: 4}
"""


def wait_for(condition, what: str, timeout_s: float = DEADLINE_S, every_s: float = 0.1):  # noqa: ANN001, ANN201
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        found = condition()
        if found:
            return found
        time.sleep(every_s)
    raise AssertionError(f"timed out waiting for {what}")


def states(out: Path) -> dict[str, int]:
    """Trial states in DIR/study.db, read as optuna-dashboard would read them (0 before the study exists)."""
    import optuna

    if not (out / "study.db").exists():
        return {}
    try:
        study = optuna.load_study(study_name="gantry-twin-tune", storage=f"sqlite:///{out / 'study.db'}")
    except Exception:  # the study is being created
        return {}
    found: dict[str, int] = {}
    for t in study.get_trials(deepcopy=False):
        found[t.state.name] = found.get(t.state.name, 0) + 1
    return found


def finished(out: Path) -> int:
    s = states(out)
    return s.get("COMPLETE", 0) + s.get("PRUNED", 0)


def _driver(spec: Path, out: Path, *args: str) -> subprocess.Popen:
    """The driver in a process of its own, its output to files (a pipe nobody reads would block it)."""
    argv = [sys.executable, "-m", "gantry_twin.cli", "tune", str(spec), "--out", str(out), "--no-progress", *args]
    log = spec.parent / "driver.log"
    with open(log, "wb") as fh:
        return subprocess.Popen(
            argv, stdout=fh, stderr=subprocess.STDOUT, env=os.environ.copy(), start_new_session=True
        )


def until(driver: subprocess.Popen, condition):  # noqa: ANN001, ANN201
    """``condition``, failing at once (with the driver's output) if the driver has exited."""

    def check():  # noqa: ANN202
        if driver.poll() is not None:
            log = Path(driver.args[4]).parent / "driver.log"
            raise AssertionError(f"the driver exited ({driver.returncode}): {log.read_text()[-2000:]}")
        return condition()

    return check


@pytest.mark.exhaustive  # a Dask cluster with a worker killed mid-trial; run with -m exhaustive
def test_a_worker_killed_mid_trial_and_the_study_completes(tmp_path, scheduler):  # noqa: F811
    from distributed import Client

    spec = tmp_path / "tune.yaml"
    spec.write_text(SPEC)
    out = tmp_path / "out"
    driver = _driver(spec, out, "--scheduler", scheduler)
    try:
        with Client(scheduler, timeout=30) as client:
            wait_for(until(driver, lambda: finished(out) >= 1), "the first trial")
            busy = wait_for(lambda: [w for w, keys in client.processing().items() if keys], "a busy worker")[0]
            pid = client.run(os.getpid, workers=[busy])[busy]
            os.kill(pid, signal.SIGKILL)
            driver.wait(timeout=DEADLINE_S)
            assert driver.returncode == 0, (tmp_path / "driver.log").read_text()[-2000:]
            assert pid not in client.run(os.getpid).values()
    finally:
        if driver.poll() is None:
            driver.kill()
    s = states(out)
    # Every trial of the budget finished; the killed one was run again elsewhere or, at worst, is the one lost.
    assert s.get("COMPLETE", 0) + s.get("PRUNED", 0) + s.get("FAIL", 0) == TRIALS, s
    assert s.get("FAIL", 0) <= 1 and "RUNNING" not in s, s
    assert (out / "tuned.yaml").is_file() and (out / "summary.md").is_file()


@pytest.mark.exhaustive  # the driver SIGKILLed, then --resume; run with -m exhaustive
def test_killed_driver_then_resume_runs_only_the_remaining_trials(tmp_path, capsys):
    import psutil

    spec = tmp_path / "tune.yaml"
    spec.write_text(SPEC)
    out = tmp_path / "out"
    driver = _driver(spec, out, "--workers", "2")
    children: list = []
    try:
        wait_for(until(driver, lambda: finished(out) >= 2), "two trials")
        children = psutil.Process(driver.pid).children(recursive=True)
        os.kill(driver.pid, signal.SIGKILL)
        driver.wait(timeout=30)
        psutil.wait_procs(children, timeout=30)
    finally:
        for proc in [driver, *children]:  # only the processes this test started
            with contextlib.suppress(Exception):
                proc.kill()
    before = finished(out)
    assert 2 <= before < TRIALS, "the driver was killed too late to leave trials to run"
    code, stdout, err = run_main(["tune", str(spec), "--out", str(out), "--workers", "2", "--resume"], capsys)
    assert code == 0, err
    assert f"{TRIALS - before} trials now, {before} before" in stdout, stdout
    s = states(out)
    assert s.get("COMPLETE", 0) + s.get("PRUNED", 0) == TRIALS and "RUNNING" not in s, s
