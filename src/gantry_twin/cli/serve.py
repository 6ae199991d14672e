"""``gantry-twin serve SCENARIO``: run a scenario and serve it as a machine over OPC UA (docs/live-link.md)."""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from gantry_twin.cli.common import (
    EXIT_OK,
    EXIT_RUN_FAILED,
    PROG,
    BadInput,
    check_writable,
    number_type,
    out_dir,
    scenario_path,
)
from gantry_twin.outputs.rundirs import point_latest
from gantry_twin.plant.model import short_label

#: The longest --wait-subscribers waits, s.
WAIT_S = 60.0
#: The default endpoint's port (OPC UA's registered port).
DEFAULT_PORT = 4840
#: Simulated seconds between two hand-overs of samples to the server when paced: 100 samples, so that at real
#: time a sample waits at most this long for its block (unpaced, the loop's own chunk: fewer calls).
SERVE_CHUNK_S = 0.02


#: --realtime: a factor > 0, or ``max`` (as fast as it runs: inf).
_realtime = number_type("FACTOR", "a number > 0 (1 = real time) or max", 0.0, lo_open=True, words={"max": math.inf})
_port = number_type("PORT", "an integer 0-65535 (0: any free port)", 0, 65535, integer=True)
_linger = number_type("SECONDS", "a number 0-3600", 0.0, 3600.0)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", nargs="?", help="scenario YAML file or shipped scenario name")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default: 127.0.0.1, loopback)")
    parser.add_argument(
        "--port", type=_port, default=DEFAULT_PORT, help=f"port (default: {DEFAULT_PORT}; 0: a free port, printed)"
    )
    parser.add_argument(
        "--realtime",
        metavar="FACTOR",
        type=_realtime,
        default=1.0,
        help="pace to the wall clock: sim time / wall time = FACTOR (default 1); max: as fast as it runs",
    )
    parser.add_argument("--loop", action="store_true", help="repeat the scenario until stopped (Ctrl-C)")
    parser.add_argument(
        "--linger",
        metavar="SECONDS",
        type=_linger,
        default=3.0,
        help="keep serving this long after the last pass, for subscribers to read the end (default 3)",
    )
    parser.add_argument(
        "--wait-subscribers",
        metavar="N",
        type=int,
        default=0,
        help="start the run only when N clients subscribe (at most 60 s; default 0: at once)",
    )
    parser.add_argument(
        "--users", metavar="FILE", type=Path, help="users allowed in (salted hashes; needed off loopback)"
    )
    parser.add_argument(
        "--out",
        metavar="DIR",
        type=Path,
        help="the run's directory (default: a new runs/<scenario name>/<UTC time>-<id>/); with --loop, one per pass",
    )


def command(args: argparse.Namespace) -> int:
    from gantry_twin.scenario import build, load_scenario

    path = scenario_path(args.scenario)
    scenario = load_scenario(path, list(args.overrides), args.controller)
    # the output location before the server starts: --out, or a new run directory under runs/ (made per pass)
    base = check_writable(args.out) if args.out is not None else None
    if base is None:
        out_dir(None, scenario)
    built = build(scenario, str(path))

    from gantry_twin.cli.printing import format_health
    from gantry_twin.link.security import Security, SecurityError
    from gantry_twin.link.server import LinkError, LinkObserver, Served, TwinServer
    from gantry_twin.run import RunWriter
    from gantry_twin.telemetry.sinks import RealtimePacer

    try:
        security = Security.for_host(args.host, args.users)
    except SecurityError as exc:
        raise BadInput(str(exc)) from None
    served = Served(
        str(scenario.name), short_label(scenario.plant.label), scenario.controller.name, built.plant.timestep_s
    )
    try:
        server = TwinServer(served, args.host, args.port, security).__enter__()
    except LinkError as exc:
        raise BadInput(str(exc)) from None
    status = EXIT_OK
    hand_over_s = 0.0
    try:
        port = server.bound_port
        print(f"serving {scenario.name} on opc.tcp://{args.host}:{port} (Ctrl-C stops)", flush=True)
        if args.wait_subscribers > 0 and not server.wait_for_subscribers(args.wait_subscribers, WAIT_S):
            raise BadInput(f"--wait-subscribers {args.wait_subscribers}: not that many subscribed within {WAIT_S:g} s")
        passes, index, offset_s = 0, 0, 0.0
        while True:
            passes += 1
            if passes > 1:
                built = build(scenario, str(path))  # a fresh controller and plant for each pass
            out = _pass_dir(base, scenario, passes, args.loop)
            try:
                writer = RunWriter(out, built, args.overrides, args.controller, plots=False)
            except OSError as exc:
                raise BadInput(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
            with writer:
                pace = 0.0 if math.isinf(args.realtime) else args.realtime
                link = LinkObserver(server, index, offset_s, _describe(scenario), pace)
                pacer = [] if math.isinf(args.realtime) else [RealtimePacer(args.realtime)]
                # Ctrl-C or SIGTERM keeps the pass as served so far (status: stopped), then stops serve
                outcome = writer.run([link, *pacer], chunk_s=SERVE_CHUNK_S if pacer else None, keep_stopped=True)
            index, offset_s = link.end_index, offset_s + (link.end_index - link.first_index) * built.plant.timestep_s
            hand_over_s += link.cpu_s
            if args.out is None:
                point_latest(out)
            failed_run = outcome.failed and link.stopped is None
            what = f"stopped ({link.stopped})" if link.stopped else "failed" if failed_run else "finished"
            print(f"pass {passes}: {what}, {index} samples served; results in {out}/", flush=True)
            if outcome.summary.health is not None:
                print("\n".join(format_health(outcome.summary.health)), flush=True)
            if failed_run:
                server.put(("state", "failed"))
                status = EXIT_RUN_FAILED
                break
            if link.stopped is None and args.loop:
                continue
            if link.stopped == "Reset":
                index, offset_s = 0, 0.0
            server.put(("state", "idle" if link.stopped else "finished"))
            # Stopped: idle until a client's Start (or Ctrl-C). Finished: --linger seconds for a Start, then the end.
            started, reset = _wait_for_start(server, math.inf if link.stopped else args.linger)
            if reset:
                index, offset_s = 0, 0.0
            if not started:
                break
        server.drain()
        if status != EXIT_OK:
            time.sleep(args.linger)  # subscribers read the state failed
    finally:
        server.close()
    total = server.thread_cpu_s + hand_over_s
    print(
        f"serving cost {total:.2f} s of CPU: the server's thread {server.thread_cpu_s:.2f} s (its start included), "
        f"handing samples over {hand_over_s:.2f} s",
        flush=True,
    )
    return status


def _wait_for_start(server, timeout_s: float) -> tuple[bool, bool]:
    """(a client called Start within ``timeout_s``, a client called Reset meanwhile: the next pass's samples count
    from 0 again)."""
    deadline, reset = time.monotonic() + timeout_s, False
    while True:
        command = server.next_command(min(1.0, deadline - time.monotonic()))
        reset = reset or command == "Reset"
        if command == "Start":
            return True, reset
        if time.monotonic() >= deadline:
            return False, reset


def _pass_dir(base: Path | None, scenario, passes: int, loop: bool) -> Path:
    """A pass's run directory: a new one under runs/ for each; with --out, DIR itself for a single pass, and
    DIR/pass-NNNN for each pass of --loop or started again by a client's Start after the first."""
    if base is None:
        return out_dir(None, scenario)
    return base / f"pass-{passes:04d}" if loop or passes > 1 else base


def _describe(scenario):
    """An alarm's event message: the alarm (parameter, time, estimate, baseline) and the monitor's threshold."""
    monitor = scenario.monitor

    def describe(alarm) -> str:
        if alarm.parameter.startswith("dN"):
            tolerance = f"{monitor.tolerance_dn_v:g} V"
        else:
            tolerance = f"{monitor.tolerance_pct:g} % of the baseline"
        return (
            f"{PROG}: alarm: {alarm.describe()}; threshold: the deviation beyond {tolerance} summed (CUSUM) "
            f"past {monitor.decision_interval_s:g} tolerance-seconds"
        )

    return describe
