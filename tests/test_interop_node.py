"""An independent OPC UA stack at the other end of the live link: node-opcua (npm), the most used stack outside C,
as a client of ``gantry-twin serve`` (docs/live-link.md).

Needs Node.js and ``npm ci`` in tests/interop (``.ci/run`` does it); without them the tests are skipped, saying so.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from .test_live_link import FAST_DRIFT, _start_serve, _stop

INTEROP = Path(__file__).resolve().parent / "interop"
NODE = shutil.which("node")
pytestmark = pytest.mark.skipif(
    NODE is None or not (INTEROP / "node_modules" / "node-opcua").is_dir(),
    reason="node-opcua is not installed: run `npm ci` in tests/interop (Node.js 20 and npm; .ci/run does it)",
)


def _node_client(endpoint: str, seconds: float, *credentials: str) -> dict:
    done = subprocess.run(
        [NODE, str(INTEROP / "twin_client.mjs"), endpoint, str(seconds), *credentials],
        cwd=INTEROP,
        capture_output=True,
        text=True,
        timeout=seconds + 60,
    )
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]  # node-opcua logs lines too
    assert lines, f"no JSON from the node client (exit {done.returncode}): {done.stdout[-2000:]} {done.stderr[-2000:]}"
    return json.loads(lines[-1])


def test_node_opcua_browses_reads_counts_every_sample_and_gets_the_alarm(tmp_path):
    serve, endpoint = _start_serve(
        tmp_path,
        "friction_drift_circle",
        *FAST_DRIFT,
        *("--realtime", "2", "--wait-subscribers", "1", "--linger", "2", "--out", str(tmp_path / "run")),
    )
    try:
        seen = _node_client(endpoint, 60.0)  # a bound: the client ends at the state finished (7 s at --realtime 2)
        serve.wait(120)
    finally:
        _stop(serve)
    assert seen["error"] is None, seen["error"]
    assert {"CncInterface", "GantryTwin"} <= set(seen["browsed"]) and isinstance(seen["actPos"], int | float)
    first, n = (np.array([b[i] for b in seen["blocks"]], dtype=np.int64) for i in (0, 1))
    assert first[0] == 0 and np.all(first[1:] == first[:-1] + n[:-1]) and n.sum() == 70_000  # every sample
    assert seen["finished"]
    assert [e for e in seen["events"] if "B2 up" in e["message"] and "threshold" in e["message"]], seen["events"]


def test_node_opcua_with_a_wrong_password_is_refused(tmp_path):
    from gantry_twin.link.security import user_entry

    users = tmp_path / "users.yaml"
    users.write_text(json.dumps({"users": {"ann": user_entry("right", "operator")}}))
    serve, endpoint = _start_serve(tmp_path, "no_load_circle", "--users", str(users), "--out", str(tmp_path / "r"))
    try:
        refused = _node_client(endpoint, 1.0, "ann", "wrong")
        admitted = _node_client(endpoint, 1.0, "ann", "right")
    finally:
        _stop(serve)
    assert refused["error"] is not None and refused["blocks"] == []
    assert admitted["error"] is None


@contextlib.contextmanager
def _node_machine(*args: str):
    """machine_server.mjs ARGS (a node-opcua machine) in a process of its own: its endpoint once it listens; the
    process waited for (60 s) and stopped on leaving, also when the test fails."""
    machine = subprocess.Popen(
        [NODE, str(INTEROP / "machine_server.mjs"), *args],
        cwd=INTEROP,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        endpoint = None
        for _ in range(50):  # node-opcua prints its own lines first
            line = machine.stdout.readline()
            if line.startswith("listening "):
                endpoint = line.split()[1]
                break
        assert endpoint, "the node-opcua machine did not start"
        yield endpoint
        machine.wait(60)
    finally:
        _stop(machine)


def test_monitor_opcua_follows_a_node_opcua_machine_as_monitor_log_reads_its_trace(tmp_path):
    """A recorded trace of a fault run, published by node-opcua as blocks of 500 samples: the shadow's alarms and
    their times are those of monitor --log on the same trace."""
    from gantry_twin.cli import main
    from gantry_twin.outputs.summary import RunSummary

    run = tmp_path / "run"
    assert main(["run", "friction_drift_circle", *FAST_DRIFT, "--out", str(run), "--no-plots"]) == 0
    assert main(["export", str(run), "--csv", "--out", str(tmp_path / "trace.csv")]) == 0
    assert (
        main(["monitor", "friction_drift_circle", *FAST_DRIFT, "--log", str(run), "--out", str(tmp_path / "log")]) == 0
    )
    with _node_machine(str(tmp_path / "trace.csv"), "500") as endpoint:
        shadow = tmp_path / "shadow"
        follow = subprocess.run(
            [sys.executable, "-m", "gantry_twin", "monitor", "friction_drift_circle", *FAST_DRIFT]
            + ["--opcua", endpoint, "--out", str(shadow), "--duration", "120"],
            capture_output=True,
            text=True,
            timeout=180,
        )
    assert follow.returncode == 0, follow.stderr
    live, log = RunSummary.read(shadow / "summary.json"), RunSummary.read(tmp_path / "log" / "summary.json")
    assert (live.live.samples, live.live.gaps, live.live.mode) == (70_000, 0, "blocks")
    block_s = 500 * 2e-4
    assert [a.parameter for a in live.health.alarms] == [a.parameter for a in log.health.alarms] == ["B2"]
    for a, b in zip(live.health.alarms, log.health.alarms, strict=True):
        assert abs(a.time_s - b.time_s) <= block_s


def test_monitor_opcua_reads_a_node_opcua_machines_scalar_values_a_sample_per_source_time(tmp_path):
    """node-opcua as a machine that publishes scalars (no blocks), every sample with its source time, the 0.2 ms
    steps in the DataValue's picoseconds: the shadow puts each sample together and reads every one node-opcua
    reports, exactly, at its own time."""
    import pyarrow.parquet as pq

    from gantry_twin.cli import main
    from gantry_twin.outputs.summary import RunSummary

    # node-opcua compares source timestamps to the millisecond, so a value that repeats within one (an axis at
    # rest: x turning back at the circle's side) is not reported (docs/live-link.md); the test says which.
    run, n, start = tmp_path / "run", 3000, 2000
    assert main(["run", "no_load_circle", "--set", "duration_s=1", "--out", str(run), "--no-plots"]) == 0
    assert main(["export", str(run), "--csv", "--out", str(tmp_path / "trace.csv")]) == 0
    node = "nsu=urn:gantry-twin:opcua;s=GantryTwin.{}"
    signals = {"x_m": "x_meas_m", "y_m": "y_meas_m", "u_x_v": "u_x_v", "u_y_v": "u_y_v"}
    units = {"x_m": "m", "y_m": "m", "u_x_v": "V", "u_y_v": "V"}
    nodes = {
        "sample_period_s": 2e-4,
        "run_state": node.format("RunState"),
        "signals": {k: {"node": node.format(v), "unit": units[k]} for k, v in signals.items()},
    }
    (tmp_path / "nodes.yaml").write_text(json.dumps(nodes))
    with _node_machine(str(tmp_path / "trace.csv"), "500", "scalars", str(n), str(start)) as endpoint:
        shadow = tmp_path / "shadow"
        follow = subprocess.run(
            [
                sys.executable,
                "-m",
                "gantry_twin",
                "monitor",
                "--opcua",
                endpoint,
                "--nodes",
                str(tmp_path / "nodes.yaml"),
            ]
            + ["--out", str(shadow), "--duration", "60"],
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert follow.returncode in (0, 5), follow.stderr  # 5: too short for the monitor's baseline, said so
    live = RunSummary.read(shadow / "summary.json").live
    sent = pq.read_table(run / "trace.parquet")
    rows = slice(start, start + n)
    # What node-opcua reports, computed here: a value is reported unless it equals the last one reported with a
    # source time in the same millisecond. A sample lacking any signal is not a sample: a gap.
    millisecond = np.floor(np.rint(sent.column("t_s").to_numpy()[rows] * 1e4) / 10)
    reported = np.ones(n, dtype=bool)
    for name in signals.values():
        values, last = sent.column(name).to_numpy()[rows], None
        for k in range(n):
            if last is not None and values[k] == last[0] and millisecond[k] == last[1]:
                reported[k] = False
            else:
                last = (values[k], millisecond[k])
    expected = np.flatnonzero(reported)
    parts = sorted((shadow / "trace").glob("part-*.parquet"))
    t = np.concatenate([pq.read_table(p).column("t_s").to_numpy() for p in parts])
    x = np.concatenate([pq.read_table(p).column("x_m").to_numpy() for p in parts])
    got = np.rint((t - t[0]) / 2e-4).astype(int) + expected[0]
    # The last sample is complete once the next one's values start coming, or the run state finished comes.
    assert live.mode == "scalars" and live.samples in (expected.size - 1, expected.size) and expected.size < n, live
    np.testing.assert_array_equal(got, expected[: got.size])  # every sample node-opcua reported, at its own time
    np.testing.assert_array_equal(x, sent.column("x_meas_m").to_numpy()[rows][got])  # with its own values


def _netns_available() -> bool:
    """An unprivileged network namespace of our own (``unshare -rn``) where a second address can go on its loopback."""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return False
    probe = subprocess.run(
        ["unshare", "-rn", "sh", "-c", f"ip link set lo up && ip addr add {OFF_LOOPBACK}/32 dev lo"],
        capture_output=True,
        timeout=10,
    )
    return probe.returncode == 0


#: An address that is not loopback, on the loopback device of a network namespace of the test's own: the server
#: treats it as off loopback (security required), and nothing it sends can leave the namespace.
OFF_LOOPBACK = "10.99.0.1"


@pytest.mark.skipif(not _netns_available(), reason="needs `unshare -rn` and `ip` (user network namespaces)")
def test_node_opcua_is_refused_without_credentials_when_serve_is_bound_off_loopback(tmp_path):
    """serve bound to a non-loopback address (inside a network namespace of its own) with --users: it offers only
    Basic256Sha256 SignAndEncrypt, so node-opcua without credentials and without a secure channel is refused; and
    without --users serve refuses to start there at all."""
    from gantry_twin.link.security import user_entry

    users = tmp_path / "users.yaml"
    users.write_text(json.dumps({"users": {"ann": user_entry("right", "operator")}}))
    cli = " ".join([sys.executable, "-m", "gantry_twin"])
    serve = f"{cli} serve no_load_circle --host {OFF_LOOPBACK} --port 48401 --out {tmp_path / 'run'}"
    client = f"{NODE} {INTEROP / 'twin_client.mjs'} opc.tcp://{OFF_LOOPBACK}:48401 2"
    script = f"""
        set -u
        ip link set lo up && ip addr add {OFF_LOOPBACK}/32 dev lo
        timeout 60 {serve} > {tmp_path / "bare.out"} 2> {tmp_path / "bare.err"}; echo "bare exit $?"
        timeout 120 {serve} --users {users} > {tmp_path / "serve.out"} 2>&1 &
        pid=$!
        for i in $(seq 1 600); do grep -q serving {tmp_path / "serve.out"} && break; sleep 0.1; done
        (cd {INTEROP} && timeout 60 {client}) | grep '^{{' | tail -1 > {tmp_path / "anonymous.json"}
        (cd {INTEROP} && timeout 60 {client} ann right) | grep '^{{' | tail -1 > {tmp_path / "plain.json"}
        kill $pid; wait $pid
    """
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config")}  # the server's certificate goes here
    done = subprocess.run(
        ["unshare", "-rn", "sh", "-c", script], capture_output=True, text=True, timeout=300, cwd=tmp_path, env=env
    )
    assert "bare exit 2" in done.stdout, (done.stdout, done.stderr)
    bare = (tmp_path / "bare.err").read_text().strip().splitlines()
    assert len(bare) == 1 and "--users" in bare[0], bare
    assert "serving" in (tmp_path / "serve.out").read_text()
    anonymous = json.loads((tmp_path / "anonymous.json").read_text())
    plain = json.loads((tmp_path / "plain.json").read_text())
    for refused in (anonymous, plain):  # neither gets a session, let alone a value or a block
        assert refused["error"] is not None and refused["actPos"] is None and refused["blocks"] == [], refused
        assert "SecurityPolicy#None" in refused["error"], refused  # the server offers no endpoint without security
