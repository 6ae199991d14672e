"""The live link's costs (docs/live-link.md, "Measured"): what serving costs a run, lag at real time, and whether
the shadow monitor keeps up.

    python benchmarks/bench_live_link.py [--seconds 60] [--repeats 3] [--skip-realtime]

Prints, from one run on one machine:

* **Cost at --realtime max**: serving's own CPU (the server thread's ``time.thread_time`` and the hand-over's, as
  serve prints them) over the rest of the serve process; and, for the whole picture, the CPU (user + sys of the
  child process, every thread, ``os.wait4``) of
  ``gantry-twin serve SCENARIO --realtime max`` with one subscriber reading every block, against
  ``gantry-twin run`` of the same scenario (``--no-plots``), interleaved, ``--repeats`` times; the median ratio.
  Both processes import the same packages and load the same compiled loop.
* **Real time**: ``serve --realtime 1`` for ``--seconds`` with one subscriber (publishing interval 20 ms):
  samples received and gaps, and the lag of each block (the wall time it arrived minus the wall time its last
  sample was due, ``RunStartedAt + t / RealtimeFactor``): median, 99th percentile, max. The serve process's CPU
  over the wall time.
* **Hostile clients**: the run's wall time at ``--realtime max`` seen by one subscriber (first block to the state
  finished), alone and beside 200 idle sessions, 1000 monitored items (asked for in ten subscriptions; the server
  takes its cap of them) and a client that stops reading; the median ratio of ``--repeats`` pairs; then the same
  at ``--realtime 1`` (a machine's pace), the run's wall over its simulated time.
* **Shadow at --realtime 4**: ``serve --realtime 4`` followed by ``monitor --opcua``: the most blocks ever waiting
  in the shadow's queue (``live.backlog_max_items``), samples followed, and how long after the machine finished
  the shadow ended.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CLI = [sys.executable, "-m", "gantry_twin"]
#: The benchmark subscriber's publishing interval, ms: a subscriber's own interval adds to the lag it sees, up to
#: one interval; 20 ms is the server's own publication period.
PUBLISHING_INTERVAL_MS = 20
SCENARIO = "no_load_circle"


def _serving_cost(proc: subprocess.Popen) -> float:
    """The CPU seconds serve says serving cost (its server thread and the hand-over), from its last line."""
    match = re.search(r"serving cost ([0-9.]+) s of CPU", proc.stdout.read())
    return float(match.group(1)) if match else math.nan


def _child_cpu(proc: subprocess.Popen) -> float:
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return usage.ru_utime + usage.ru_stime


def _serve(tmp: Path, *args: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([*CLI, "serve", SCENARIO, "--port", "0", *args], cwd=tmp, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    match = re.search(r"(opc\.tcp://127\.0\.0\.1:\d+)", line)
    if match is None:
        proc.kill()
        raise SystemExit(f"serve did not start: {line!r}")
    return proc, match.group(1)


def _subscriber(endpoint: str, seconds: float, out: str) -> None:
    """Subscribe to the sample blocks until the run state is finished (or ``seconds``); write what came."""
    from gantry_twin.link.blocks import decode
    from gantry_twin.link.client import asyncua_client

    arrivals: list[tuple[float, int, int, float]] = []  # (arrived s, first index, samples, last t)
    state = {"finished": False}

    class Handler:
        def datachange_notification(self, node, value, data):
            if node.nodeid.Identifier.endswith("SampleBlock"):
                block = decode(value)
                if block is not None:
                    arrivals.append((time.time(), block.first_index, block.samples, float(block.values[-1, 0])))
            elif value == "finished":
                state["finished"] = True

    async def main():
        async with asyncua_client(endpoint, 10.0) as client:
            idx = await client.get_namespace_index("urn:gantry-twin:opcua")
            block = client.get_node(f"ns={idx};s=GantryTwin.SampleBlock")
            run_state = client.get_node(f"ns={idx};s=GantryTwin.RunState")
            sub = await client.create_subscription(PUBLISHING_INTERVAL_MS, Handler())
            await sub.subscribe_data_change([block, run_state], queuesize=500, sampling_interval=0)
            deadline = time.monotonic() + seconds
            while not state["finished"] and time.monotonic() < deadline:
                await asyncio.sleep(0.1)
            started = await client.get_node(f"ns={idx};s=GantryTwin.RunStartedAt").read_value()
            factor = await client.get_node(f"ns={idx};s=GantryTwin.RealtimeFactor").read_value()
            await asyncio.sleep(0.3)  # the state came after the last block: nothing more is due
        Path(out).write_text(json.dumps({"arrivals": arrivals, "started": started, "factor": factor}))

    asyncio.run(main())


def _subscribe(endpoint: str, seconds: float, out: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, __file__, "--subscriber", endpoint, str(seconds), str(out)])


def _cost_pair(tmp: Path, seconds: float, tag: str) -> tuple[float, float, int]:
    """CPU of ``run`` and of ``serve --realtime max`` with one subscriber, ``seconds`` simulated; samples read."""
    duration = f"duration_s={seconds}"
    run = subprocess.Popen(
        [*CLI, "run", SCENARIO, "--set", duration, "--no-plots", "--out", str(tmp / f"run{tag}")],
        stdout=subprocess.DEVNULL,
    )
    run_cpu = _child_cpu(run)
    serve, endpoint = _serve(
        tmp, "--set", duration, "--realtime", "max", "--wait-subscribers", "1", "--linger", "1", "--out", str(tmp / tag)
    )
    sub = _subscribe(endpoint, 600, tmp / f"cost{tag}.json")
    serving = _serving_cost(serve)
    serve_cpu = _child_cpu(serve)
    sub.wait(120)
    arrivals = json.loads((tmp / f"cost{tag}.json").read_text())["arrivals"]
    return run_cpu, serve_cpu, sum(a[2] for a in arrivals), serving


def cost(tmp: Path, seconds: float, repeats: int) -> None:
    """Whole processes, and the margin: (serve(S) - serve(S/4)) / (run(S) - run(S/4)), which leaves out what both
    pay once (imports, the compiled loop's load, the server's start and --linger)."""
    short = seconds / 4
    print(f"Cost at --realtime max ({SCENARIO}), CPU s of the process, all threads; {short:g} s and {seconds:g} s:")
    whole, margin, own = [], [], []
    for i in range(repeats):
        run_s, serve_s, got_s, _ = _cost_pair(tmp, short, f"s{i}")
        run_l, serve_l, got_l, serving = _cost_pair(tmp, seconds, f"l{i}")
        whole.append(serve_l / run_l)
        margin.append((serve_l - serve_s) / (run_l - run_s))
        own.append(serving / (serve_l - serving))
        print(
            f"  {short:g} s: run {run_s:6.2f}  serve {serve_s:6.2f} ({got_s} samples read) | "
            f"{seconds:g} s: run {run_l:6.2f}  serve {serve_l:6.2f} ({got_l} samples read), of it serving "
            f"{serving:.2f} | whole {whole[-1]:.3f}  margin {margin[-1]:.3f}  serving / the rest {own[-1]:.3f}"
        )
    print(
        f"  median serve / run: whole process {np.median(whole):.3f}, per simulated second {np.median(margin):.3f}; "
        f"serving's own CPU (server thread + hand-over) / the rest of the serve process: {np.median(own):.3f}"
    )


def realtime(tmp: Path, seconds: float) -> None:
    print(f"Real time (--realtime 1, {seconds:g} s), one subscriber:")
    serve, endpoint = _serve(
        tmp, "--set", f"duration_s={seconds}", "--wait-subscribers", "1", "--linger", "1", "--out", str(tmp / "rt")
    )
    sub = _subscribe(endpoint, seconds + 60, tmp / "rt.json")
    wall = time.monotonic()
    serve_cpu = _child_cpu(serve)
    wall = time.monotonic() - wall
    sub.wait(120)
    data = json.loads((tmp / "rt.json").read_text())
    arrivals = np.array(data["arrivals"])
    first, n = arrivals[:, 1].astype(int), arrivals[:, 2].astype(int)
    contiguous = bool(np.all(first[1:] == first[:-1] + n[:-1])) and first[0] == 0
    lag_ms = (arrivals[:, 0] - (data["started"] + arrivals[:, 3] / data["factor"])) * 1e3
    print(
        f"  samples received {int(n.sum())} of {int(round(seconds / 2e-4))}, in {len(n)} blocks, no gap: {contiguous}"
    )
    print(
        f"  lag per block: median {np.median(lag_ms):.1f} ms, p99 {np.percentile(lag_ms, 99):.1f} ms, "
        f"max {lag_ms.max():.1f} ms"
    )
    print(f"  serve CPU {serve_cpu:.2f} s over {wall:.1f} s wall ({100 * serve_cpu / wall:.0f} % of one core)")


def shadow(tmp: Path, seconds: float) -> None:
    print(f"Shadow at --realtime 4 ({seconds:g} s simulated):")
    serve, endpoint = _serve(
        tmp,
        "--set",
        f"duration_s={seconds}",
        "--realtime",
        "4",
        "--wait-subscribers",
        "1",
        "--linger",
        "2",
        "--out",
        str(tmp / "s4"),
    )
    follow = subprocess.Popen(
        [*CLI, "monitor", "--opcua", endpoint, "--out", str(tmp / "m4"), "--duration", str(seconds + 60)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    serve.wait(600)
    finished = time.monotonic()
    follow.wait(600)
    after = time.monotonic() - finished
    live = json.loads((tmp / "m4" / "summary.json").read_text())["live"]
    print(
        f"  followed {live['samples']} samples, gaps {live['gaps']}; most blocks waiting at once "
        f"{live['backlog_max_items']}; the shadow ended {after:.1f} s after serve ({live['ended_by']})"
    )
    print(f"  blocks waiting, once a second: {live['backlog_items_per_s']}")


#: The subscriptions that monitor something in the hostile case: the subscriber (2 items), the deaf client (1), and
#: the four of the ten asking for 100 items that the server's total cap (400) lets in (100, 100, 100, 97).
HOSTILE_SUBSCRIBERS = 6


async def _hostile_run(endpoint: str, hostile: bool) -> tuple[float, int]:
    """One subscriber reading every block, beside (``hostile``) 200 idle sessions, 1000 monitored items asked for
    in ten subscriptions (the server takes MAX_MONITORED_ITEMS of them) and a client that stops reading its
    socket, all set up before the run starts; (the run's wall time from its first block to its state finished,
    the samples read)."""
    from gantry_twin.link.blocks import decode
    from gantry_twin.link.client import asyncua_client

    logging.getLogger("asyncua").setLevel(logging.CRITICAL)  # the idle clients' complaints when serve ends
    state = {"first": None, "finished": None, "samples": 0}

    class Legit:
        def datachange_notification(self, node, value, data):
            if isinstance(value, str):
                if value == "finished":
                    state["finished"] = time.monotonic()
            elif (block := decode(value)) is not None:
                state["first"] = state["first"] or time.monotonic()
                state["samples"] += block.samples

    class Ignore:
        def datachange_notification(self, node, value, data):
            pass

    idle = []
    if hostile:
        for _ in range(200):
            client = asyncua_client(endpoint, 10.0)
            await client.connect()
            idle.append(client)
    legit = asyncua_client(endpoint, 10.0)
    await legit.connect()
    ns = await legit.get_namespace_index("urn:gantry-twin:opcua")
    block, run_state = (legit.get_node(f"ns={ns};s=GantryTwin.{n}") for n in ("SampleBlock", "RunState"))
    sub = await legit.create_subscription(PUBLISHING_INTERVAL_MS, Legit())
    await sub.subscribe_data_change([block, run_state], queuesize=500, sampling_interval=0)  # quiet: the run starts
    if hostile:  # the run starts with the last of these (serve --wait-subscribers HOSTILE_SUBSCRIBERS)
        deaf = await idle[1].create_subscription(50, Ignore())
        await deaf.subscribe_data_change([idle[1].get_node(block.nodeid)], queuesize=10_000, sampling_interval=0)
        idle[1].uaclient.protocol.transport.pause_reading()
        for client in idle[10:20]:  # 1000 in ten subscriptions of 100: as many as the server's caps let in
            many = await client.create_subscription(100, Ignore())
            position = client.get_node(f"ns={ns};s=CncInterface.CncAxisList.X.PosDirect.ActPos")
            await many.subscribe_data_change([position] * 100, queuesize=1)
    deadline = time.monotonic() + 600
    while state["finished"] is None and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    await legit.disconnect()
    return state["finished"] - state["first"], state["samples"]


def _hostile_pair(tmp: Path, seconds: float, pace: str, tag: str) -> dict[str, tuple[float, float, float, int]]:
    """Quiet, then hostile, at ``--realtime pace``: (the run's wall s from first block to finished, the serve
    process's CPU s over all its threads, serving's own CPU s, samples read) for each."""
    result = {}
    for mode in ("quiet", "hostile"):
        serve, endpoint = _serve(
            tmp,
            *("--set", f"duration_s={seconds}", "--realtime", pace),
            *("--wait-subscribers", str(HOSTILE_SUBSCRIBERS if mode == "hostile" else 1)),
            *("--linger", "0.5", "--out", str(tmp / f"h{mode}{tag}")),
        )
        try:
            wall, got = asyncio.run(_hostile_run(endpoint, mode == "hostile"))
            serving = _serving_cost(serve)
            result[mode] = (wall, _child_cpu(serve), serving, got)
        finally:
            if serve.poll() is None:
                serve.kill()
        wall, cpu, serving, got = result[mode]
        print(f"  {mode:8s} wall {wall:6.2f} s, serve CPU {cpu:6.2f} s (serving {serving:5.2f} s), {got} samples read")
    return result


def hostile(tmp: Path, seconds: float, repeats: int) -> None:
    """At --realtime max the wall time measures how much of the machine's cores the run gets: on a 2-core machine
    the hostile clients' own process (here, this one) takes a core's share too. At --realtime 1 (serve's default,
    a machine's pace) the run must keep its pace: wall over simulated time."""
    print(f"Hostile clients at --realtime max ({seconds:g} s simulated): the run's wall time, quiet and hostile:")
    ratios = []
    for i in range(repeats):
        pair = _hostile_pair(tmp, seconds, "max", str(i))
        ratios.append(pair["hostile"][0] / pair["quiet"][0])
    print(f"  median hostile / quiet: {np.median(ratios):.3f}")
    paced = min(seconds, 20.0)
    print(f"Hostile clients at --realtime 1 ({paced:g} s simulated): the run's wall time over its simulated time:")
    pair = _hostile_pair(tmp, paced, "1", "rt")
    print(
        f"  quiet {pair['quiet'][0] / paced:.3f}, hostile {pair['hostile'][0] / paced:.3f} "
        f"(hostile / quiet {pair['hostile'][0] / pair['quiet'][0]:.3f})"
    )


def main() -> None:
    if len(sys.argv) == 5 and sys.argv[1] == "--subscriber":
        _subscriber(sys.argv[2], float(sys.argv[3]), sys.argv[4])
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--skip-realtime", action="store_true")
    parser.add_argument("--only", choices=("cost", "realtime", "shadow", "hostile"), help="run one part")
    args = parser.parse_args()
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        if args.only in (None, "cost"):
            cost(Path(tmp), args.seconds, args.repeats)
        if args.only == "realtime" or (args.only is None and not args.skip_realtime):
            realtime(Path(tmp), args.seconds)
        if args.only in (None, "shadow"):
            shadow(Path(tmp), min(args.seconds, 40.0))
        if args.only in (None, "hostile"):
            hostile(Path(tmp), args.seconds, args.repeats)


if __name__ == "__main__":
    main()
