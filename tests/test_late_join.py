"""Shadow mode joins a machine that is already running (docs/live-link.md, "Joining a running machine"): the
monitor's windows count from the first sample it followed, and ``monitor --log`` on the shadow's own trace agrees.

Every server listens on 127.0.0.1 on a free port; every process a test starts is stopped in a ``finally``; every
wait is bounded.
"""

from __future__ import annotations

import asyncio
import signal
import subprocess
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gantry_twin.cli import main
from gantry_twin.outputs.summary import RunSummary

from .test_live_link import CLI, WAIT_S, FakeMachine, _Follow, _start_serve, _stop

#: friction_drift_circle made to fit a short test: the baseline window 4-7 s (of the monitor's own time), the
#: drift of B2 +30 % at 48-51 s of the machine's time, a 60 s pass. A shadow that joins at the machine's t = 8-40 s
#: (after the machine's own baseline window) takes its baseline from its own 4-7 s, before the drift.
LATE = (
    *("--set", "duration_s=60", "--set", "monitor.baseline_window_s=[4,7]"),
    *("--set", "changes.friction_drift=[{axis: y, start_s: 48, end_s: 51, viscous_to_v_s_m: 0.91}]"),
)
JOIN_AFTER_S, JOIN_BEFORE_S, STOP_AT_S = 8.0, 40.0, 56.0


def _wait_machine_time(endpoint: str, t_s: float) -> float:
    """Wait (bounded) until the machine's ``GantryTwin.Time`` reaches ``t_s``; the time read."""
    from gantry_twin.link.client import asyncua_client

    async def wait() -> float:
        async with asyncua_client(endpoint, 10.0) as client:
            ns = await client.get_namespace_index("urn:gantry-twin:opcua")
            node = client.get_node(f"ns={ns};s=GantryTwin.Time")
            deadline = time.monotonic() + WAIT_S
            while (now := float(await node.read_value())) < t_s:
                assert time.monotonic() < deadline, f"the machine did not reach t = {t_s:g} s within {WAIT_S:g} s"
                await asyncio.sleep(0.05)
            return now

    return asyncio.run(wait())


def _log_of_parts(shadow: Path, log: Path) -> Path:
    """The shadow's trace parts, in order, as one log file (``monitor --log`` reads one file)."""
    parts = sorted((shadow / "trace").glob("part-*.parquet"))
    pq.write_table(pa.concat_tables([pq.read_table(p) for p in parts]), log)
    return log


def test_a_shadow_that_joins_late_takes_its_baseline_from_its_own_first_seconds(tmp_path):
    """Acceptance: serve a drift scenario with --loop; two shadows join after the machine's baseline window has
    passed in its own time. One takes its baseline from its own 4-7 s, the other is given a healthy run's
    summary (--baseline: no window); both raise the drift's B2 alarm, and ``monitor --log`` on each one's own trace
    raises it at the same time since the first sample (to 0.1 s) and the same machine time."""
    healthy = tmp_path / "healthy"  # a run of the machine without the drift: its estimates are the baseline
    assert main(["run", "friction_drift_circle", "--set", "duration_s=10", "--set", "changes.friction_drift=[]"]
                + ["--set", "monitor.enable=false", "--out", str(healthy), "--no-plots"]) == 0  # fmt: skip
    # The shadows' kernels (the estimator's replay, the monitor) compiled now, not while a shadow should join: on a
    # cold cache a shadow started at the machine's t = 8 s joined after its drift (and judged nothing).
    main(["monitor", "friction_drift_circle", *LATE, "--log", str(healthy / "trace.parquet"), "--out",
          str(tmp_path / "warm"), "--no-plots"])  # fmt: skip
    serve, endpoint = _start_serve(tmp_path, "friction_drift_circle", *LATE, "--loop", "--realtime", "4")
    shadows = {"window": tmp_path / "window", "given": tmp_path / "given"}
    extra = {"window": [], "given": ["--baseline", str(healthy / "summary.json")]}
    procs: dict[str, subprocess.Popen] = {}
    try:
        _wait_machine_time(endpoint, JOIN_AFTER_S)
        for name, out in shadows.items():
            procs[name] = subprocess.Popen(
                [*CLI, "monitor", "friction_drift_circle", *LATE, "--opcua", endpoint, "--out", str(out)]
                + ["--duration", str(WAIT_S), "--residual-every", "60", *extra[name]],
                cwd=tmp_path,
                stdout=open(tmp_path / f"{name}.out", "w"),  # noqa: SIM115 (closed with the process)
                stderr=open(tmp_path / f"{name}.err", "w"),  # noqa: SIM115
            )
        _wait_machine_time(endpoint, STOP_AT_S)
        for proc in procs.values():
            proc.send_signal(signal.SIGTERM)  # what came is kept: summary.json is written
        for proc in procs.values():
            proc.wait(WAIT_S)
    finally:
        _stop(*procs.values(), serve)
    for name, out in shadows.items():
        err = (tmp_path / f"{name}.err").read_text()
        assert procs[name].returncode == 0, (name, err)
        live = RunSummary.read(out / "summary.json")
        first = live.live.first_t_s
        assert JOIN_AFTER_S <= first <= JOIN_BEFORE_S, f"{name}: joined at {first} s, outside the test's design"
        assert live.live.gaps == 0 and live.live.ended_by.startswith("an interrupt")
        alarms = live.health.alarms
        assert [(a.parameter, a.direction) for a in alarms[:1]] == [("B2", "up")], (name, alarms)
        b2 = alarms[0]
        assert 48.0 < b2.time_s < STOP_AT_S  # the drift's, in the machine's time
        assert b2.since_start_s == pytest.approx(b2.time_s - first, abs=1e-9)  # and in the shadow's own
        assert f"({b2.since_start_s:.2f} s after the first sample)" in (tmp_path / f"{name}.out").read_text()
        if name == "window":
            source = live.health.baseline["source"]
            assert f"mean over 4-7 s from its first sample (t = {first + 4:.6g}-{first + 7:.6g} s)" in source
        else:
            assert live.health.baseline["source"].startswith("commissioning run")
        # monitor --log on the trace the shadow wrote: its windows count from the log's first sample too
        logged = tmp_path / f"{name}-log"
        log = _log_of_parts(out, tmp_path / f"{name}.parquet")
        assert main(["monitor", "friction_drift_circle", *LATE, "--log", str(log), "--out", str(logged)]
                    + extra[name]) == 0  # fmt: skip
        by_log = RunSummary.read(logged / "summary.json").health.alarms
        assert [a.parameter for a in by_log] == [a.parameter for a in alarms]
        for a, s in zip(by_log, alarms, strict=True):
            assert abs(a.since_start_s - s.since_start_s) <= 0.1 and abs(a.time_s - s.time_s) <= 0.1


def test_a_shadow_whose_duration_ends_before_its_baseline_window_says_so_at_the_start(tmp_path, capsys):
    """--duration 6 s at a machine that runs at 3x real time follows 18 s of it: the default baseline window,
    20-30 s from the first sample, is never reached. One line says so on connecting, before any sample came, and
    the exit 5 line names the window and what to do."""
    out = tmp_path / "o"
    with FakeMachine() as machine:
        machine.server.put(("started", time.time(), 3.0))  # serve's RealtimeFactor: 3x real time
        follow = _Follow(capsys, machine.endpoint, out, "--duration", "6")
        try:
            machine.wait_for_subscriber()
            deadline, seen = time.monotonic() + WAIT_S, ""
            while "nothing will be judged" not in seen:
                assert time.monotonic() < deadline and follow.poll() is None, seen
                time.sleep(0.05)
                seen += capsys.readouterr().err
            machine.send(50_000, 5000)  # the machine, already 10 s into its run
            _, err = follow.communicate(timeout=WAIT_S)
        finally:
            _stop(follow)
    warning = [line for line in seen.splitlines() if "nothing will be judged" in line]
    assert warning == [
        "monitor: --duration 6 s follows about 18 s of the machine's time (it runs at 3x real time): that ends "
        "before the monitor's baseline window 20-30 s (monitor.baseline_window_s), counted from the first sample "
        "followed; give --baseline SUMMARY (a healthy run's or shadow's summary.json), or a --duration that covers "
        "30 s of the machine's time; nothing will be judged"
    ]
    last = err.strip().splitlines()[-1]
    assert follow.returncode == 5, err
    assert "monitor judged nothing" in last and "it followed 1 s of the machine's time" in last
    assert "baseline window 20-30 s (monitor.baseline_window_s)" in last and "--baseline SUMMARY" in last
    assert RunSummary.read(out / "summary.json").live.first_t_s == pytest.approx(10.0)


def test_the_first_stop_signal_is_a_request_the_second_stops_at_once():
    """A shadow follows until a stop signal, read between two chunks (a SIGTERM raised inside a chunk's bookkeeping
    once left the monitor's history half-written); a second signal raises as any command's does."""
    import os
    import threading

    from gantry_twin.outputs.signals import Interrupted, stop_signals_request

    before = signal.getsignal(signal.SIGTERM)
    stop, went_on = threading.Event(), False
    with pytest.raises(Interrupted), stop_signals_request(stop):
        os.kill(os.getpid(), signal.SIGTERM)
        deadline = time.monotonic() + 10.0
        while not stop.is_set() and time.monotonic() < deadline:
            time.sleep(0.01)
        went_on = stop.is_set()  # the first one only asked
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(10.0)  # the second one raises within this
    assert went_on and signal.getsignal(signal.SIGTERM) is before
