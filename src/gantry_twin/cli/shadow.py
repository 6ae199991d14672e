"""``gantry-twin monitor [SCENARIO] --opcua ENDPOINT``: the twin follows a running machine (docs/live-link.md)."""

from __future__ import annotations

import argparse
import sys
import threading
from pathlib import Path

from gantry_twin.cli.common import (
    EXIT_ALARM,
    EXIT_NOT_JUDGED,
    EXIT_OK,
    PROG,
    RUNS_DIR,
    BadInput,
    checked_out,
    number_type,
    scenario_path,
    writable_out,
)

_seconds = number_type("SECONDS", "a number in (0, 604800]", 0.0, 7 * 24 * 3600.0, lo_open=True)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("shadow mode (OPC UA)")
    group.add_argument("--opcua", metavar="ENDPOINT", help="follow the machine at opc.tcp://HOST:PORT")
    group.add_argument(
        "--nodes", metavar="FILE", type=Path, help="node map YAML (default: gantry-twin serve's address space)"
    )
    group.add_argument("--duration", metavar="SECONDS", type=_seconds, help="stop after this much wall time")
    group.add_argument(
        "--residual-every",
        metavar="SECONDS",
        type=_seconds,
        default=5.0,
        help="replay a 1 s window through the twin's plant every SECONDS of the machine's time (default 5)",
    )
    group.add_argument(
        "--connect-timeout",
        metavar="SECONDS",
        type=_seconds,
        default=10.0,
        help="how long to try the first connection (default 10)",
    )


def command(args: argparse.Namespace, format_health) -> int:
    from gantry_twin.cli.monitor import monitor_settings
    from gantry_twin.cli.telemetry import telemetry_observers
    from gantry_twin.link.nodemap import NodeMapError, default_node_map, read_node_map
    from gantry_twin.link.shadow import Shadow, ShadowError, short_of_judging
    from gantry_twin.loop.trace import RunInfo
    from gantry_twin.outputs.files import atomic_write_text
    from gantry_twin.outputs.rundirs import new_run_dir, point_latest
    from gantry_twin.outputs.signals import stop_signals_request
    from gantry_twin.outputs.summary import log_summary, summary_json
    from gantry_twin.scenario import ScenarioError, build, scenario_plant

    endpoint = args.opcua
    if not endpoint.startswith("opc.tcp://"):
        raise BadInput(f"--opcua {endpoint}: an endpoint like opc.tcp://127.0.0.1:4840")
    if getattr(args, "realtime", None) is not None:
        raise BadInput("--realtime: not with --opcua (the machine sets the pace)")
    try:
        nodes = read_node_map(args.nodes) if args.nodes is not None else default_node_map()
    except NodeMapError as exc:
        raise BadInput(str(exc)) from None
    path = None if args.scenario is None else scenario_path(args.scenario)
    try:
        scenario, controller, monitor = monitor_settings(args, path, "--opcua")
    except ValueError as exc:
        raise BadInput(str(exc).splitlines()[0]) from None
    try:
        plant = scenario_plant(scenario, False, str(path) if path else "<defaults>")
    except ScenarioError as exc:
        raise BadInput(str(exc).splitlines()[0]) from None
    label = endpoint.removeprefix("opc.tcp://").replace(":", "_").replace("/", "_")
    out = checked_out(args.out) if args.out is not None else new_run_dir(checked_out(RUNS_DIR / f"{label}-monitor"))

    def print_alarm(alarm) -> None:
        print(f"{PROG}: alarm: {alarm.describe()}", flush=True)

    telemetry = telemetry_observers(args)  # checks every option (--viewer, --save, ...) before anything opens
    run_info = None
    if telemetry.rerun_observer is not None:  # the dashboard draws the scenario's path, the machine's on it
        try:
            built = build(scenario, str(path) if path else "<defaults>")
        except ScenarioError as exc:
            raise BadInput(str(exc).splitlines()[0]) from None
        samples = round(scenario.duration_s / built.plant.timestep_s)
        name = f"DIARC following {endpoint}"
        run_info = RunInfo(built.plant, built.path, built.timing, None, scenario.duration_s, name, samples)
        telemetry.rerun_observer.watch(monitor)
    with writable_out(out), telemetry:
        shadow = Shadow(
            *(endpoint, nodes, controller, monitor, plant, plant.timestep_s, out, print_alarm, None),
            *(args.residual_every, list(telemetry), run_info),
        )
        print(f"following {endpoint} ({nodes.mode}); Ctrl-C stops", file=sys.stderr, flush=True)
        stop = threading.Event()
        try:
            with stop_signals_request(stop):  # the first stop signal ends the stream between two chunks
                shadow.run(args.duration, args.connect_timeout, stop)
        except ShadowError as exc:
            raise BadInput(str(exc)) from None
    if shadow.s.samples < 2 or shadow.estimator is None:
        raise BadInput(
            f"--opcua {endpoint}: {shadow.s.samples} valid samples came ({shadow.s.invalid} with NaN); nothing to judge"
        )
    tally = shadow.finish()
    summary = log_summary(shadow.info(), tally, shadow.live_section())
    atomic_write_text(out / "summary.json", summary_json(summary))
    if args.out is None:
        point_latest(out)
    live = summary.live
    assert live is not None
    residual = (
        f"; residual rms {_axes(live.residual_rms_um)} um, max {_axes(live.residual_max_um)} um over "
        f"{live.residual_windows} windows"
        if live.residual_rms_um
        else ""
    )
    print(
        f"followed {live.samples} samples ({live.covered_s:.3g} s, {live.mode}); gaps {live.gaps} "
        f"({live.missing_samples} samples), reconnects {live.reconnects}; ended by {live.ended_by}{residual}",
        flush=True,
    )
    print("\n".join([*format_health(summary.health), f"results in {out}/ (summary.json, trace/)"]), flush=True)
    if not summary.health.judged:
        short = short_of_judging(monitor, live.covered_s)
        why = f": it followed {live.covered_s:.3g} s of the machine's time; {short}" if short else ""
        print(f"{PROG}: monitor judged nothing (health.judged is empty in {out}/summary.json){why}", file=sys.stderr)
        return EXIT_NOT_JUDGED
    return EXIT_ALARM if args.fail_on_alarm and summary.health.alarms else EXIT_OK


def _axes(values: dict[str, float] | None) -> str:
    return "/".join(f"{v:.3g}" for v in (values or {}).values())
