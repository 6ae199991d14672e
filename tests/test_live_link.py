"""The live link over OPC UA (docs/live-link.md): ``gantry-twin serve`` and ``gantry-twin monitor --opcua``.

Every server listens on 127.0.0.1 on a port the system picks (``--port 0``, read from serve's first line);
every process a test starts is killed in a ``finally``; every wait is bounded.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from gantry_twin.cli import main
from gantry_twin.link import server
from gantry_twin.link.blocks import SIGNALS, Block, BlockError, decode
from gantry_twin.outputs.summary import RunSummary
from gantry_twin.telemetry.observer import theta_entity

from .helpers import FLOAT32_REL, read_rrd, scalars

#: A fast friction drift: the scenario's B2 +30 % moved to 7-10 s of a 14 s run, the baseline to 4-7 s (one
#: alarm, B2's, at 9.4 s: the same as the 90 s scenario says at 50 s, in a sixth of the time).
FAST_DRIFT = (
    "--set",
    "duration_s=14",
    "--set",
    "monitor.baseline_window_s=[4,7]",
    "--set",
    "changes.friction_drift=[{axis: y, start_s: 7, end_s: 10, viscous_to_v_s_m: 0.91}]",
)
CLI = [sys.executable, "-m", "gantry_twin"]
WAIT_S = 120.0


def _start_serve(tmp_path: Path, *args: str) -> tuple[subprocess.Popen, str]:
    """serve in a process of its own on a free loopback port; (process, endpoint) once it listens."""
    proc = subprocess.Popen(
        [*CLI, "serve", *args, "--port", "0"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    line = proc.stdout.readline()  # "serving NAME on opc.tcp://127.0.0.1:PORT (Ctrl-C stops)"
    match = re.search(r"(opc\.tcp://127\.0\.0\.1:\d+)", line)
    if match is None:
        proc.kill()
        raise AssertionError(f"serve did not start: {line!r} {proc.stderr.read()!r}")
    return proc, match.group(1)


def _stop(*procs: subprocess.Popen) -> None:
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait(30)


def test_a_served_run_followed_by_the_shadow_monitor_gives_monitor_logs_estimates_and_alarms(tmp_path):
    """Two processes: serve at --realtime max, monitor --opcua; then monitor --log on the served run's trace."""
    served, shadow, logged = tmp_path / "served", tmp_path / "shadow", tmp_path / "logged"
    serve, endpoint = _start_serve(
        tmp_path,
        "friction_drift_circle",
        *FAST_DRIFT,
        "--realtime",
        "max",
        "--wait-subscribers",
        "1",
        "--out",
        str(served),
        "--linger",
        "2",
    )
    try:
        follow = subprocess.run(
            [*CLI, "monitor", "friction_drift_circle", *FAST_DRIFT, "--opcua", endpoint, "--duration", "100"]
            + ["--out", str(shadow), "--residual-every", "1", "--save", str(tmp_path / "shadow.rrd")],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=WAIT_S,
        )
        serve.wait(WAIT_S)
    finally:
        _stop(serve)
    assert serve.returncode == 0, serve.stderr.read()
    assert follow.returncode == 0, follow.stderr
    assert main(["monitor", "friction_drift_circle", *FAST_DRIFT, "--log", str(served), "--out", str(logged)]) == 0

    live, log = RunSummary.read(shadow / "summary.json"), RunSummary.read(logged / "summary.json")
    samples = pq.read_metadata(served / "trace.parquet").num_rows
    assert live.live.samples == samples == 70_000 and live.live.gaps == 0 and live.live.missing_samples == 0
    assert live.live.first_index == 0 and live.live.mode == "blocks" and live.live.reconnects == 0
    assert live.live.ended_by == "the machine's run state finished"
    for name, estimate in log.estimates.items():
        assert live.estimates[name].estimate == pytest.approx(estimate.estimate, rel=1e-12, abs=1e-15), name
    alarms = [(a.parameter, a.time_s, a.estimate) for a in log.health.alarms]
    assert [(a.parameter, a.time_s, a.estimate) for a in live.health.alarms] == alarms
    assert [a[0] for a in alarms] == ["B2"]  # the drifting parameter, and only it
    assert "alarm: t = " in follow.stdout and "B2 up" in follow.stdout  # printed as it happened
    # The trace came as it went, in parts each readable on its own: every sample, in order.
    parts = sorted((shadow / "trace").glob("part-*.parquet"))
    t = np.concatenate([pq.read_table(p).column("t_s").to_numpy() for p in parts])
    assert t.size == samples and np.all(np.diff(t) > 0)
    # The residual, measured minus the twin's own plant driven by the machine's commands in 1 s windows, is
    # the twin's fidelity: micrometres while the machine is the twin's plant, and on Y alone, growing, once the
    # machine's B2 drifts from it (a drift of 0.21 V/(m/s) at 0.4 m/s is 5.8 N on 34.5 kg: centimetres in 1 s).
    rows = np.loadtxt(shadow / "residual.csv", delimiter=",", skiprows=1)
    # From 1 s: the first window holds the run's start, whose friction state is not the steady one each window
    # of the replay starts from (sysid/replay.py).
    before, after = rows[(rows[:, 0] >= 1.0) & (rows[:, 0] + 1.0 <= 7.0)], rows[rows[:, 0] >= 10.0]
    assert len(rows) == live.live.residual_windows >= 12 and len(before) >= 4 and len(after) >= 2
    assert before[:, 1:3].max() < 100.0  # rms, um
    assert np.all(after[:, 2] > 10 * after[:, 1]) and after[:, 2].min() > 1000.0
    assert live.log == endpoint
    # The dashboard (--save here, --viewer alike) got the shadow's estimates as they came, and its alarm.
    data = read_rrd(tmp_path / "shadow.rrd")
    theta = np.concatenate([pq.read_table(p).column("theta_hat_B2").to_numpy() for p in parts])
    logged = data[theta_entity("B2") + "/estimate"]
    at = np.rint(np.asarray(logged["time_ns"]) * 1e-9 / 2e-4).astype(int)
    assert at.size > 100 and np.all(np.diff(at) > 0)
    np.testing.assert_allclose(scalars(data, theta_entity("B2") + "/estimate")[:, 0], theta[at], rtol=FLOAT32_REL)
    assert any("B2" in str(text) for text in data["health/alarms"]["TextLog:text"])


def test_the_trust_flags_of_each_closed_monitor_period_are_handed_to_the_server():
    """GantryTwin/Trusted follows the health monitor: after each chunk, the last closed period's flags (excited and
    its bias within bounds, per estimate); nothing while no period has closed."""
    import queue

    from gantry_twin.health.log_monitor import chunk_trace
    from gantry_twin.link.server import LinkObserver
    from gantry_twin.sysid.logs import LogChunk

    class Server:
        def __init__(self):
            self.items, self.commands = [], queue.Queue()

        def put(self, item):
            self.items.append(item)

    class Monitor:  # closes periods as a test says: rows of trusted flags
        alarms: list = []
        periods = np.zeros((0, 8))

        def trusted_since(self, row):
            return np.arange(len(self.periods))[row:], self.periods[row:]

    server, monitor = Server(), Monitor()
    link = LinkObserver(server)
    link.watch(monitor)
    n = 10
    chunk = LogChunk(0, np.arange(3 * n) * 2e-4, np.zeros((3 * n, 2)), np.zeros((3 * n, 2)), None)
    trace = chunk_trace(chunk, np.zeros((3 * n, 8)), 2e-4)
    flags = np.array([[1, 0, 1, 0, 1, 0, 1, 0], [1, 1, 1, 1, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0, 0, 1]], dtype=float)
    published = []
    for k, closed in enumerate((0, 2, 3)):  # no period, then two at once (the last one counts), then one more
        monitor.periods = flags[:closed]
        link.on_chunk(trace, k * n, (k + 1) * n)
        published.append([item[1] for item in server.items if item[0] == "trusted"])
    assert published[0] == []
    assert published[1] == [[True, True, True, True, False, False, False, False]]
    assert published[2][-1] == [False] * 7 + [True] and len(published[2]) == 2


def test_shadow_refuses_realtime_the_machine_sets_the_pace(tmp_path, capsys):
    args = ["monitor", "--opcua", "opc.tcp://127.0.0.1:9", "--realtime", "1", "--out", str(tmp_path / "o")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["gantry-twin: error: --realtime: not with --opcua (the machine sets the pace)"]
    assert not (tmp_path / "o").exists()


def test_blocks_round_trip_and_refuse_what_is_not_one():
    rng = np.random.default_rng(3)
    values = rng.normal(size=(7, len(SIGNALS)))
    block = Block(123_456, 24.6912, values)
    back = decode(block.encode())
    assert back.first_index == 123_456 and back.first_time_s == 24.6912 and np.array_equal(back.values, values)
    assert decode([]) is None  # a server's value before its first block
    for bad in ([1.0, 2.0], [0, 0, 2, len(SIGNALS), *range(5)], [-1, 0, 1, len(SIGNALS), *range(len(SIGNALS))]):
        with pytest.raises(BlockError):
            decode(bad)


def test_serve_refuses_a_non_loopback_address_without_users(tmp_path, capsys):
    assert main(["serve", "no_load_circle", "--host", "192.0.2.1", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--host 192.0.2.1" in err[0] and "--users FILE" in err[0]
    assert not (tmp_path / "o").exists()


def test_users_file_roles_and_permissions(tmp_path):
    from asyncua import ua

    from gantry_twin.link.security import Security, SecurityError, _Permissions, _Users, read_users, user_entry

    users = tmp_path / "users.yaml"
    users.write_text(
        json.dumps({"users": {"ann": user_entry("s3cret", "operator"), "bob": user_entry("pw-bob", "viewer")}})
    )
    accounts = read_users(users)
    manager, permissions = _Users(accounts, anonymous=False), _Permissions(accounts)
    assert manager.get_user(None) is None  # no anonymous off loopback
    assert manager.get_user(None, "ann", "wrong") is None and manager.get_user(None, "eve", "s3cret") is None
    ann, bob = manager.get_user(None, "ann", "s3cret"), manager.get_user(None, "bob", "pw-bob")
    call = ua.NodeId(ua.ObjectIds.CallRequest_Encoding_DefaultBinary)
    write = ua.NodeId(ua.ObjectIds.WriteRequest_Encoding_DefaultBinary)
    read = ua.NodeId(ua.ObjectIds.ReadRequest_Encoding_DefaultBinary)
    assert permissions.check_validity(ann, call, None) and not permissions.check_validity(bob, call, None)
    assert not permissions.check_validity(ann, write, None)  # nobody writes a variable
    assert permissions.check_validity(bob, read, None)
    assert Security.for_host("192.0.2.1", users).secured and not Security.for_host("127.0.0.1", None).secured
    with pytest.raises(SecurityError, match="users.x.role"):
        users.write_text(json.dumps({"users": {"x": {**user_entry("p"), "role": "root"}}}))
        read_users(users)


def test_shadow_of_a_machine_that_is_not_there_is_one_line_and_exit_2(tmp_path, capsys):
    import socket

    with socket.socket() as s:  # a free port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code = main(["monitor", "--opcua", f"opc.tcp://127.0.0.1:{port}", "--connect-timeout", "1", "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and "no machine answered within 1 s" in err[-1] and len(err[-1].splitlines()) == 1


@pytest.fixture(scope="module")
def idle_server(tmp_path_factory):
    """serve waiting for a subscriber that never comes: a machine whose address space is there."""
    tmp = tmp_path_factory.mktemp("idle")
    proc, endpoint = _start_serve(tmp, "no_load_circle", "--wait-subscribers", "50", "--out", str(tmp / "o"))
    try:
        yield endpoint
    finally:
        _stop(proc)


@pytest.mark.parametrize(
    ("signals", "expected"),
    [
        ({"x_m": "nsu=urn:gantry-twin:opcua;s=NoSuchNode"}, "node nsu=urn:gantry-twin:opcua;s=NoSuchNode (x_m)"),
        ({"x_m": "nsu=urn:gantry-twin:opcua;s=GantryTwin.ContourError"}, None),
        ({"x_m": "nsu=urn:gantry-twin:opcua;s=GantryTwin.Command"}, "its EngineeringUnits are V"),
        ({"x_m": "nsu=urn:no-such-namespace;s=X"}, "the server has no namespace urn:no-such-namespace"),
    ],
    ids=["missing_node", "command_on_a_position", "wrong_unit", "missing_namespace"],
)
def test_shadow_node_map_errors_name_the_node(idle_server, tmp_path, capsys, signals, expected):
    twin = "nsu=urn:gantry-twin:opcua;s=CncInterface.CncAxisList"
    mapping = {
        "x_m": f"{twin}.X.PosDirect.ActPos",
        "y_m": f"{twin}.Y.PosDirect.ActPos",
        "u_x_v": f"{twin}.X.PosDirect.ActPos",
        "u_y_v": f"{twin}.Y.PosDirect.ActPos",
        **signals,
    }
    units = {"x_m": "m", "y_m": "m", "u_x_v": "V", "u_y_v": "V"}
    nodes = tmp_path / "nodes.yaml"
    body = {"sample_period_s": 0.0002, "signals": {k: {"node": v, "unit": units[k]} for k, v in mapping.items()}}
    nodes.write_text(json.dumps(body))
    args = ["monitor", "--opcua", idle_server, "--nodes", str(nodes), "--duration", "2", "--out", str(tmp_path / "o")]
    code = main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err[-1].splitlines()) == 1
    if expected is None:  # u_x_v mapped onto a position in metres: refused for its unit, before any sample
        assert "u_x_v" in err[-1] and "EngineeringUnits are m" in err[-1]
    else:
        assert expected in err[-1]


def test_node_map_file_errors_name_the_field(tmp_path, capsys):
    nodes = tmp_path / "nodes.yaml"
    for body, field in (
        ({"sample_period_s": 0}, "sample_period_s"),
        ({"sample_period_s": 2e-4, "signals": {"x_m": {"node": "ns=2;s=X", "unit": "mm"}}}, "signals.x_m.unit"),
        ({"sample_period_s": 2e-4, "blocks": "not a node"}, "blocks"),
        ({"sample_period_s": 2e-4, "signals": {"x_m": {"node": "ns=2;s=X", "unit": "m"}}}, "lacks u_x_v"),
        ({"period": 1}, "unknown key 'period'"),
    ):
        nodes.write_text(json.dumps(body))
        assert main(["monitor", "--opcua", "opc.tcp://127.0.0.1:1", "--nodes", str(nodes)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"--nodes {nodes}" in err[0] and field in err[0], err


def test_a_killed_shadow_leaves_a_readable_trace(tmp_path):
    """SIGKILL mid-stream: every part file there is complete, and they hold consecutive samples."""
    serve, endpoint = _start_serve(
        tmp_path, "no_load_circle", "--realtime", "max", "--loop", "--out", str(tmp_path / "s")
    )
    shadow = tmp_path / "shadow"
    follow = subprocess.Popen(
        [*CLI, "monitor", "--opcua", endpoint, "--out", str(shadow), "--duration", "60"],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + WAIT_S
        while len(list((shadow / "trace").glob("part-*.parquet"))) < 3 and time.monotonic() < deadline:
            time.sleep(0.1)
        os.kill(follow.pid, signal.SIGKILL)
        follow.wait(30)
    finally:
        _stop(follow, serve)
    parts = sorted((shadow / "trace").glob("part-*.parquet"))
    assert len(parts) >= 3
    t = np.concatenate([pq.read_table(p).column("t_s").to_numpy() for p in parts])
    assert np.allclose(np.diff(t), 2e-4, rtol=0, atol=1e-9)


class FakeMachine:
    """A machine that publishes the blocks a test writes (serve's own server, fed by hand): a context manager."""

    def __init__(self, port: int = 0) -> None:
        from gantry_twin.link.security import Security
        from gantry_twin.link.server import Served, TwinServer

        self.server = TwinServer(Served("fake", "fake plant", "diarc", 2e-4), "127.0.0.1", port, Security("127.0.0.1"))

    def __enter__(self) -> FakeMachine:
        self.server.__enter__()
        self.endpoint = f"opc.tcp://127.0.0.1:{self.server.bound_port}"
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.close()

    def wait_for_subscriber(self) -> None:
        assert self.server.wait_for_subscribers(1, 30.0), "no subscriber came within 30 s"

    def send(self, first_index: int, n: int, fill: float | None = None, time_too: bool = False) -> None:
        """Samples [first_index, first_index + n): a slow circle (or ``fill`` in every signal but the time, and in
        the time too with ``time_too``), one block."""
        k = np.arange(first_index, first_index + n, dtype=float)
        values = np.zeros((n, len(SIGNALS)))
        values[:, 0] = k * 2e-4
        values[:, 1], values[:, 2] = 0.1 * np.cos(k * 2e-4), 0.1 * np.sin(k * 2e-4)
        values[:, 7], values[:, 8] = np.cos(k * 2e-4), np.sin(k * 2e-4)
        if fill is not None:
            values[:, 0 if time_too else 1 :] = fill
        self.server.put(("samples", np.column_stack([values, k])))
        self.server.drain()

    def finish(self) -> None:
        self.server.put(("state", "finished"))
        self.server.drain()

    def wait_delivered(self, timeout_s: float = 30.0) -> None:
        """Wait (bounded) until every subscription has published what it queued and its client acknowledged it
        (read from asyncua's server state; a sleep here lost samples to a subscriber slowed by load)."""
        subscriptions = self.server._server.iserver.subscription_service.subscriptions
        deadline = time.monotonic() + timeout_s
        while any(s._triggered_datachanges or s._not_acknowledged_results for s in list(subscriptions.values())):
            assert time.monotonic() < deadline, f"the subscriber did not read the blocks within {timeout_s:g} s"
            time.sleep(0.05)


class _Follow:
    """``monitor --opcua`` run by ``main`` in a thread of this process (no interpreter start-up: the machine is in
    this process too); its output is capsys's. Quacks like the Popen that ``_stop`` stops: it ends by itself
    (``--duration 60`` bounds it)."""

    def __init__(self, capsys, endpoint: str, out: Path, *extra: str) -> None:
        import threading

        self.capsys, self.returncode = capsys, None
        args = ["monitor", "--opcua", endpoint, "--out", str(out), "--duration", "60", *extra]
        self.thread = threading.Thread(target=self._run, args=(args,), daemon=True)
        self.thread.start()

    def _run(self, args: list[str]) -> None:
        self.returncode = main(args)

    def communicate(self, timeout: float) -> tuple[str, str]:
        self.thread.join(timeout)
        captured = self.capsys.readouterr()
        return captured.out, captured.err

    def poll(self) -> int | None:
        return self.returncode

    def kill(self) -> None:
        pass

    def wait(self, timeout: float) -> None:
        self.thread.join(timeout)


@pytest.mark.parametrize(
    ("script", "expected"),
    [
        ([(1000, 100), (500, 100)], "sample indices went back (a block from 500 after one from 1000)"),
        ([(0, 100, math.nan), (100, 100, math.nan)], "0 valid samples came (200 with NaN); nothing to judge"),
        ([(0, 100), (100, 100, -1.0, True)], None),  # times going back: t = -1 after t = 0.0198
    ],
    ids=["decreasing_indices", "only_nan", "decreasing_times"],
)
def test_shadow_refuses_a_stream_it_cannot_judge(tmp_path, capsys, script, expected):
    with FakeMachine() as machine:
        follow = _Follow(capsys, machine.endpoint, tmp_path / "o")
        try:
            machine.wait_for_subscriber()
            for step in script:
                machine.send(*step)
            machine.finish()
            _, err = follow.communicate(timeout=WAIT_S)
        finally:
            _stop(follow)
    lines = err.strip().splitlines()
    assert follow.returncode == 2 and lines and "Traceback" not in err, err
    assert (expected or "sample times went back (at t = -1 s)") in lines[-1]


def test_shadow_counts_a_gap_and_a_reconnect_and_invents_no_sample(tmp_path, capsys):
    """A machine already 10 s into its run, lost for 0.4 s and back: the gap is counted, and the monitor's windows
    go on counting from the first sample followed (its baseline window, 1-3 s of that clock, spans the reconnect;
    counted again from the reconnect it would end after the stream)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out, k0 = tmp_path / "o", 50_000
    with FakeMachine(port) as machine:
        follow = _Follow(capsys, machine.endpoint, out, "--set", "monitor.baseline_window_s=[1,3]")
        machine.wait_for_subscriber()
        machine.send(k0, 5000)
        machine.send(k0 + 5000, 5000)
        machine.wait_delivered()
    try:
        with FakeMachine(port) as machine:  # the machine back, 2000 samples later
            machine.wait_for_subscriber()
            machine.send(k0 + 12_000, 5000)
            machine.finish()
            out_text, err = follow.communicate(timeout=WAIT_S)
    finally:
        _stop(follow)
    summary = RunSummary.read(out / "summary.json")
    live = summary.live
    assert "connection to" in err and "lost" in err
    assert (live.samples, live.gaps, live.missing_samples, live.reconnects) == (15_000, 1, 2000, 1), live
    assert live.first_t_s == 10.0 and live.first_index == k0
    assert summary.health.baseline["source"] == "this run, mean over 1-3 s from its first sample (t = 11-13 s)"
    t = np.concatenate([pq.read_table(p).column("t_s").to_numpy() for p in sorted((out / "trace").glob("*.parquet"))])
    assert t.size == 15_000 and np.all(np.diff(t) > 0)  # what came, nothing in the gap


def test_a_machine_that_stalls_for_seconds_costs_the_shadow_no_reconnect(tmp_path, capsys):
    """A loaded machine's server answers late; the shadow must not take 2.5 s of silence for a lost connection
    (asyncua's own probe gives up after 1 s unless told otherwise) and must lose no sample to it."""
    out = tmp_path / "o"
    with FakeMachine() as machine:
        follow = _Follow(capsys, machine.endpoint, out)
        try:
            machine.wait_for_subscriber()
            machine.send(0, 5000)
            time.sleep(0.5)
            machine.server._loop.call_soon_threadsafe(time.sleep, 2.5)  # the server's loop answers nothing
            time.sleep(3.0)
            machine.send(5000, 5000)
            machine.finish()
            _, err = follow.communicate(timeout=WAIT_S)
        finally:
            _stop(follow)
    assert "lost" not in err, err
    live = RunSummary.read(out / "summary.json").live  # 2 s of samples: too few to judge (exit 5), all counted
    assert (live.samples, live.gaps, live.missing_samples, live.reconnects) == (10_000, 0, 0, 0), (live, err)


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return math.nan


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads a process's memory from /proc")
def test_hostile_clients_do_not_cost_a_subscriber_a_sample(tmp_path):
    """200 sessions never closed, 1000 monitored items, a browse of everything, a client that stops reading its
    socket, malformed messages and a wrong password ten times, while a subscriber reads every block."""
    import asyncio
    import socket

    from asyncua import ua

    from gantry_twin.link.blocks import decode
    from gantry_twin.link.client import asyncua_client
    from gantry_twin.link.security import user_entry

    users = tmp_path / "users.yaml"
    users.write_text(json.dumps({"users": {"ann": user_entry("right", "operator")}}))
    out = tmp_path / "run"
    serve, endpoint = _start_serve(
        tmp_path,
        "no_load_circle",
        *("--set", "duration_s=10", "--realtime", "2", "--wait-subscribers", "1", "--linger", "2"),
        *("--users", str(users), "--out", str(out)),
    )
    host, port = "127.0.0.1", int(endpoint.rsplit(":", 1)[1])
    rss = [_rss_mb(serve.pid)]
    received: list[tuple[int, int]] = []
    done = {"finished": False}
    accepted: list[int] = []  # monitored items created, per subscription
    refused: set[str] = set()

    class Legit:
        def datachange_notification(self, node, value, data):
            if isinstance(value, str):
                done["finished"] = value == "finished"
            elif (block := decode(value)) is not None:
                received.append((block.first_index, block.samples))

    class Ignore:
        def datachange_notification(self, node, value, data):
            pass

    async def hostile():
        idle = []
        for _ in range(200):  # sessions opened and never closed
            c = asyncua_client(endpoint, 10.0)
            await c.connect()
            idle.append(c)
            rss.append(_rss_mb(serve.pid))
        browsed = await _browse_all(idle[1], idle[1].nodes.root, depth=6)  # a browse of everything
        for i in range(10):  # a wrong password, ten times
            bad = asyncua_client(endpoint, 5.0)
            bad.set_user("ann")
            bad.set_password(f"wrong{i}")
            with pytest.raises((ua.UaError, OSError, TimeoutError, asyncio.TimeoutError)):
                await bad.connect()
            with contextlib.suppress(Exception):
                await bad.disconnect()
        for payload in (b"\x00" * 64, b"HELF" + b"\xff" * 60, os.urandom(4096), b"MSGF\x10\x00\x00\x00garbage"):
            with socket.create_connection((host, port), timeout=5) as s:  # malformed messages
                s.sendall(payload)
        legit = asyncua_client(endpoint, 10.0)
        await legit.connect()
        ns = await legit.get_namespace_index("urn:gantry-twin:opcua")
        sub = await legit.create_subscription(100, Legit())
        nodes = [legit.get_node(f"ns={ns};s=GantryTwin.{n}") for n in ("SampleBlock", "RunState")]
        await sub.subscribe_data_change(nodes, queuesize=500)  # the run starts now (--wait-subscribers 1)
        deaf = idle[2]  # subscribes to every block, then stops reading its socket
        s3 = await deaf.create_subscription(50, Ignore())
        await s3.subscribe_data_change(nodes[:1], queuesize=10_000)
        deaf.uaclient.protocol.transport.pause_reading()
        many = idle[0]
        scalars = [many.get_node(f"ns={ns};s=CncInterface.CncAxisList.X.PosDirect.ActPos")] * 1000
        s2 = await many.create_subscription(100, Ignore())
        created = [await s2.subscribe_data_change(scalars, queuesize=1)]  # 1000 monitored items
        for client in idle[3:8]:  # and more, over other subscriptions, until the server's total is reached
            sub_more = await client.create_subscription(100, Ignore())
            created.append(await sub_more.subscribe_data_change(scalars[:100], queuesize=1))
        accepted.extend(sum(isinstance(h, int) for h in handles) for handles in created)
        refused.update(str(h) for handles in created for h in handles if not isinstance(h, int))
        deadline = time.monotonic() + WAIT_S
        while not done["finished"] and time.monotonic() < deadline:
            rss.append(_rss_mb(serve.pid))
            await asyncio.sleep(0.2)
        await asyncio.sleep(0.5)
        with contextlib.suppress(Exception):
            await legit.disconnect()
        return browsed

    try:
        browsed = asyncio.run(hostile())
        serve.wait(WAIT_S)
    finally:
        _stop(serve)
    assert serve.returncode == 0, serve.stderr.read()
    first = np.array([r[0] for r in received])
    n = np.array([r[1] for r in received])
    assert first[0] == 0 and np.all(first[1:] == first[:-1] + n[:-1]) and n.sum() == 50_000  # every sample
    assert max(rss) - rss[0] < 200.0, f"memory grew {max(rss) - rss[0]:.0f} MB"
    assert browsed > 1000  # the standard address space and the twin's
    # Monitored items are capped per subscription and in all (the legitimate subscriber's 2 and the deaf one's 1
    # came first): the cap is what keeps 1000 items from taking the run's core.
    per, total = server.MAX_MONITORED_ITEMS_PER_SUBSCRIPTION, server.MAX_MONITORED_ITEMS
    expected = [per]
    for _ in range(5):
        expected.append(max(0, min(per, total - 3 - sum(expected))))
    assert accepted == expected, (accepted, expected)
    assert refused == {str(ua.StatusCode(ua.StatusCodes.BadTooManyMonitoredItems))}
    print(f"hostile: memory {rss[0]:.0f} -> {max(rss):.0f} MB, {browsed} nodes browsed", file=sys.stderr)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "users.yaml"]  # nothing written outside the run


async def _browse_all(client, node, depth: int) -> int:
    count = 0
    children = await node.get_children()
    for child in children:
        count += 1
        if depth > 0:
            count += await _browse_all(client, child, depth - 1)
    return count


def test_an_operator_stops_and_starts_the_twin_and_nobody_else_can(tmp_path):
    import asyncio

    from asyncua import Client, ua

    from gantry_twin.link.client import asyncua_client
    from gantry_twin.link.security import user_entry

    users = tmp_path / "users.yaml"
    entries = {"op": user_entry("op-pw", "operator"), "view": user_entry("view-pw", "viewer")}
    users.write_text(json.dumps({"users": entries}))
    out = tmp_path / "run"
    serve, endpoint = _start_serve(
        tmp_path,
        "no_load_circle",
        *("--set", "duration_s=3", "--realtime", "1", "--users", str(users), "--linger", "1", "--out", str(out)),
    )

    async def session(user: str | None = None, password: str | None = None) -> Client:
        client = asyncua_client(endpoint, 10.0)
        if user:
            client.set_user(user)
            client.set_password(password)
        await client.connect()
        return client

    async def wait_state(client: Client, ns: int, wanted: str) -> None:
        node = client.get_node(f"ns={ns};s=GantryTwin.RunState")
        deadline = time.monotonic() + 30
        while await node.read_value() != wanted:
            assert time.monotonic() < deadline, f"no {wanted} within 30 s"
            await asyncio.sleep(0.05)

    async def drive() -> None:
        op, viewer, anonymous = await session("op", "op-pw"), await session("view", "view-pw"), await session()
        ns = await op.get_namespace_index("urn:gantry-twin:opcua")
        twin = op.get_node(f"ns={ns};s=GantryTwin")
        await wait_state(op, ns, "running")
        for who in (viewer, anonymous):  # reading is everybody's; the methods are the operator's
            with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
                await who.get_node(f"ns={ns};s=GantryTwin").call_method(f"{ns}:Stop")
        with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):  # and nobody writes
            await op.get_node(f"ns={ns};s=GantryTwin.RunState").write_value("finished")
        await twin.call_method(f"{ns}:Stop")
        await wait_state(op, ns, "idle")
        await twin.call_method(f"{ns}:Start")
        await wait_state(op, ns, "running")
        for client in (op, viewer, anonymous):
            await client.disconnect()

    try:
        asyncio.run(drive())
        serve.wait(WAIT_S)
    finally:
        _stop(serve)
    assert serve.returncode == 0, serve.stderr.read()
    stopped, second = RunSummary.read(out / "summary.json"), RunSummary.read(out / "pass-0002" / "summary.json")
    assert stopped.status == "failed" and "stopped by a client's Stop" in stopped.failure.error
    assert stopped.failure.time_s < 3.0 and second.status == "ok" and second.duration_s == 3.0


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["sigint", "sigterm"])
def test_a_stopped_serve_keeps_what_it_served(tmp_path, stop):
    """``serve --loop`` stopped by SIGINT or SIGTERM 20 s (simulated) into a pass: exit 130 / 143, the sessions
    closed, and the pass's directory kept with summary.json ``status: stopped`` and a trace that holds at least every
    sample a subscriber had received (docs/live-link.md)."""
    import asyncio
    import threading

    from gantry_twin.link.blocks import decode
    from gantry_twin.link.client import asyncua_client

    out = tmp_path / "run"
    serve, endpoint = _start_serve(
        tmp_path,
        "no_load_circle",
        *("--set", "duration_s=30", "--loop", "--realtime", "8", "--wait-subscribers", "1", "--out", str(out)),
    )
    received: list[int] = []  # the end index of each block received
    quit_ = threading.Event()

    class Blocks:
        def datachange_notification(self, node, value, data):
            if (block := decode(value)) is not None:
                received.append(block.first_index + block.samples)

    async def subscribe():
        client = asyncua_client(endpoint, 10.0)
        await client.connect()
        ns = await client.get_namespace_index("urn:gantry-twin:opcua")
        sub = await client.create_subscription(50, Blocks())
        await sub.subscribe_data_change([client.get_node(f"ns={ns};s=GantryTwin.SampleBlock")], queuesize=1000)
        while not quit_.is_set():
            await asyncio.sleep(0.05)
        with contextlib.suppress(Exception):
            await client.disconnect()

    subscriber = threading.Thread(target=asyncio.run, args=(subscribe(),), daemon=True)
    subscriber.start()
    try:
        deadline = time.monotonic() + WAIT_S
        while (max(received, default=0) < 100_000) and time.monotonic() < deadline and serve.poll() is None:
            time.sleep(0.05)  # 20 s of the pass (at 8 times real time) reached the subscriber
        assert max(received, default=0) >= 100_000, serve.stderr.read() if serve.poll() is not None else ""
        serve.send_signal(stop)
        serve.wait(60)
        had = max(received)
    finally:
        quit_.set()
        _stop(serve)
        subscriber.join(30)
    err = serve.stderr.read().strip().splitlines()
    assert serve.returncode == 128 + stop and err[-1] == f"gantry-twin: interrupted ({stop.name})", err
    passes = sorted(out.iterdir())
    assert [p.name for p in passes] == ["pass-0001"]
    summary = RunSummary.read(passes[0] / "summary.json")
    rows = pq.read_metadata(passes[0] / "trace.parquet").num_rows
    assert summary.status == "stopped" and summary.failed and summary.steps == rows
    assert summary.failure.error.startswith(f"stopped by {stop.name} at t = ")
    assert rows >= had >= 100_000 and rows < 150_000  # at least what was served; 30 s is 150 000
    t = pq.read_table(passes[0] / "trace.parquet").column("t_s").to_numpy()
    assert np.all(np.diff(t) > 0) and t[0] == 0.0
    assert not list(passes[0].glob(".*.part"))


def test_shadow_reads_scalar_values_a_sample_per_source_time(tmp_path, capsys):
    """A machine that publishes its positions and commands as scalar values (no blocks), each with the sample's
    source time: the node map's signals, put together a sample per source time, every one of them."""
    import asyncio
    import datetime
    import threading

    from asyncua import Server, ua

    ready, done = threading.Event(), threading.Event()
    where: dict = {}
    n, ts = 3000, 2e-4

    async def machine():
        server = Server()
        await server.init()
        server.set_endpoint("opc.tcp://127.0.0.1:0")
        idx = await server.register_namespace("urn:a-machine")
        axis = await server.nodes.objects.add_object(idx, "Machine")
        names = ("x_m", "y_m", "u_x_v", "u_y_v")
        nodes = {k: await axis.add_variable(ua.NodeId(f"M.{k}", idx), f"{k}", 0.0) for k in names}
        state = await axis.add_variable(ua.NodeId("M.State", idx), "State", "running")
        async with server:
            where["endpoint"] = f"opc.tcp://127.0.0.1:{server.bserver.port}"
            ready.set()
            while not server.iserver.subscription_service.subscriptions:
                await asyncio.sleep(0.05)
            await asyncio.sleep(0.5)
            t0 = datetime.datetime(2026, 12, 4, tzinfo=datetime.UTC)
            for k in range(n):
                stamp = t0 + datetime.timedelta(microseconds=200 * k)
                values = {"x_m": 0.1 * np.cos(k * ts), "y_m": 0.1 * np.sin(k * ts), "u_x_v": 0.5, "u_y_v": -0.5}
                for name, value in values.items():
                    dv = ua.DataValue(ua.Variant(float(value), ua.VariantType.Double), SourceTimestamp=stamp)
                    await server.write_attribute_value(nodes[name].nodeid, dv)
                if k % 100 == 99:
                    await asyncio.sleep(0.03)  # within what a 100 ms publishing interval's queues hold
            await asyncio.sleep(0.5)
            await server.write_attribute_value(
                state.nodeid, ua.DataValue(ua.Variant("finished", ua.VariantType.String))
            )
            await asyncio.to_thread(done.wait, 60)

    thread = threading.Thread(target=lambda: asyncio.run(machine()), daemon=True)
    thread.start()
    try:
        assert ready.wait(30), "the machine did not start"
        node = "nsu=urn:a-machine;s=M.{}"
        units = {"x_m": "m", "y_m": "m", "u_x_v": "V", "u_y_v": "V"}
        nodes_file = tmp_path / "nodes.yaml"
        nodes_file.write_text(
            json.dumps(
                {
                    "sample_period_s": ts,
                    "run_state": node.format("State"),
                    "signals": {k: {"node": node.format(k), "unit": u} for k, u in units.items()},
                }
            )
        )
        out = tmp_path / "o"
        code = main(
            ["monitor", "--opcua", where["endpoint"], "--nodes", str(nodes_file), "--duration", "60"]
            + ["--out", str(out)]
        )
    finally:
        done.set()
        thread.join(30)
    err = capsys.readouterr().err
    assert code in (0, 5), err  # 5: too short a stream for the monitor's baseline window, said so
    live = RunSummary.read(out / "summary.json").live
    # The last sample is complete only once the next one's values start coming: all but at most the last.
    assert live.mode == "scalars" and live.gaps == 0 and n - 1 <= live.samples <= n, live
    assert live.ended_by == "the machine's run state finished"
