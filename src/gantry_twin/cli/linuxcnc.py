"""``gantry-twin linuxcnc config [SCENARIO] --out DIR [--live]``: a LinuxCNC configuration of the twin's machine;
``gantry-twin linuxcnc machine --ini INI``: the twin as LinuxCNC's machine, loaded by the live configuration's HAL
file (docs/linuxcnc.md)."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import shlex
import sys
from pathlib import Path

from gantry_twin.cli.common import EXIT_OK, EXIT_RUN_FAILED, PROG, RUNS_DIR, BadInput, checked_out
from gantry_twin.cnc.config import INI_NAME, SERVO_PERIOD_NS, CncConfigError, config_files, machine_for, read_ini
from gantry_twin.outputs.files import atomic_write_text
from gantry_twin.paths.contours import TimingLaw
from gantry_twin.scenario import load_scenario
from gantry_twin.scenario.files import shipped
from gantry_twin.scenario.schema import DURATION_MAX_S, GcodeSpec

#: The live mode's settings in the INI's [GANTRY_TWIN] section (docs/linuxcnc.md, "The live mode").
LIVE_KEYS = ("SCENARIO", "SET", "RUN_DIR", "RUN_BASE", "DELAY_PERIODS", "TELEMETRY")
#: The twin's messages in its live run directory (also on LinuxCNC's output).
LIVE_LOG = "linuxcnc_live.log"


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``linuxcnc`` (its ``config`` and ``machine``) to the subcommands."""
    parser = sub.add_parser("linuxcnc", help="LinuxCNC drives the twin: its configuration (docs/linuxcnc.md)")
    actions = parser.add_subparsers(dest="action", required=True, metavar="{config,machine}", parser_class=type(parser))
    config = actions.add_parser("config", help="write a LinuxCNC INI and HAL file of the twin's XY machine")
    config.add_argument(
        "scenario", nargs="?", help="a scenario whose part-program limits (contour.limits) LinuxCNC plans with"
    )
    config.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scenario field (repeatable)")  # fmt: skip
    config.add_argument("--out", metavar="DIR", type=Path, required=True, help="the configuration's directory")
    config.add_argument("--live", action="store_true",
                        help="the live mode: the twin is LinuxCNC's machine (docs/linuxcnc.md)")  # fmt: skip
    config.add_argument("--display", default="axis", metavar="PROGRAM",
                        help="LinuxCNC's [DISPLAY] DISPLAY (default axis)")  # fmt: skip
    config.add_argument("--run-dir", type=Path, metavar="DIR",
                        help="--live: the twin's run directory (default: a new one under runs/linuxcnc-live/ "
                             "each time LinuxCNC starts)")  # fmt: skip
    config.add_argument("--delay-periods", type=int, default=None, metavar="N",
                        help="--live: rows prefilled into HAL's streamer: the feedback's delay, servo periods "
                             "(default 100)")  # fmt: skip
    config.add_argument("--telemetry", default="", metavar="'ARGS'",
                        help="--live: rerun for the twin: '--serve-web', '--viewer', '--save FILE.rrd' or "
                             "'--connect URL' (docs/telemetry.md)")  # fmt: skip
    config.set_defaults(func=command)
    machine = actions.add_parser(
        "machine", help="the twin as LinuxCNC's machine (loaded by the --live configuration's HAL file)"
    )
    machine.add_argument("--ini", type=Path, required=True, metavar="INI", help="the live configuration's INI")
    machine.set_defaults(func=machine_command)


def command(args: argparse.Namespace) -> int:
    """Write DIR/gantry-twin.ini, .hal and .tbl (each replaced whole); 0."""
    from gantry_twin.cnc.live import DELAY_PERIODS
    from gantry_twin.numerics.jit import cache_dir

    limits = None
    if args.scenario is not None or args.overrides:
        scenario = load_scenario(args.scenario or shipped("no_load_circle"), args.overrides)
        if isinstance(scenario.contour, GcodeSpec) and scenario.contour.limits is not None:
            limits = scenario.contour.limits.limits()
    out = checked_out(args.out).resolve()
    live = None
    if args.live:
        delay = DELAY_PERIODS if args.delay_periods is None else args.delay_periods
        if not 1 <= delay <= 2000:
            raise BadInput(f"--delay-periods {delay}: 1 .. 2000 servo periods")
        run_dir = (args.run_dir or RUNS_DIR / "linuxcnc-live").resolve()
        settings = {
            "SCENARIO": str(Path(args.scenario).resolve()) if args.scenario and Path(args.scenario).is_file()
            else (args.scenario or "no_load_circle"),
            "SET": " ".join(shlex.quote(o) for o in args.overrides),
            "RUN_DIR": str(run_dir) if args.run_dir is not None else "",
            "RUN_BASE": str(run_dir) if args.run_dir is None else "",
            "DELAY_PERIODS": str(delay),
            "TELEMETRY": args.telemetry,
        }  # fmt: skip
        words = ["/usr/bin/env", f"NUMBA_CACHE_DIR={Path(cache_dir()).parent}", sys.executable, "-m", "gantry_twin",
                 "linuxcnc", "machine", "--ini", str(out / INI_NAME)]  # fmt: skip
        spaced = next((w for w in words if any(c.isspace() for c in w)), None)
        if spaced is not None:
            raise BadInput(f"--out {out}: HAL's loadusr line cannot hold a path with spaces ({spaced!r})")
        live = (" ".join(words), settings)
    elif args.run_dir is not None or args.delay_periods is not None or args.telemetry:
        raise BadInput("--run-dir, --delay-periods and --telemetry: only with --live")
    try:
        out.mkdir(parents=True, exist_ok=True)
        files = config_files(machine_for(limits), args.display, live)
        for name, text in files.items():
            atomic_write_text(out / name, text)
    except OSError as exc:
        raise BadInput(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    if args.live:
        # The twin's loop compiles now, once per install, not while LinuxCNC waits for its machine.
        from gantry_twin.cli import compile as compile_command
        from gantry_twin.scenario import resolve_scenario

        scenario_name = live[1]["SCENARIO"]
        name = load_scenario(resolve_scenario(scenario_name), args.overrides).controller.name
        code = compile_command.command(argparse.Namespace(controller=[name], compile_scenario=scenario_name))
        if code != EXIT_OK:
            return code
        print(f"LinuxCNC configuration of the twin as LinuxCNC's machine in {out}/ ({', '.join(files)}); run it "
              f"with `linuxcnc {out / INI_NAME}` (docs/linuxcnc.md, 'The live mode')")  # fmt: skip
        return EXIT_OK
    print(f"LinuxCNC configuration of the twin's machine in {out}/ ({', '.join(files)}); run it with "
          f"`linuxcnc {out / 'gantry-twin.ini'}`, or give the INI to `gantry-twin run PROGRAM --cnc linuxcnc "
          "--cnc-ini FILE`")  # fmt: skip
    return EXIT_OK


def machine_command(args: argparse.Namespace) -> int:
    """The twin as LinuxCNC's machine until LinuxCNC ends or estops (0) or the twin faults (1)."""
    from gantry_twin.cnc.live import (
        CHUNK_S,
        DELAY_PERIODS,
        LiveCommands,
        LiveError,
        LiveFeedback,
        LiveFifos,
    )
    from gantry_twin.loop.simulate import simulate
    from gantry_twin.numerics.jit import CacheDirError, check_cache_dir
    from gantry_twin.outputs.rundirs import new_run_dir
    from gantry_twin.outputs.tracefile import TraceParts
    from gantry_twin.run import RunWriter
    from gantry_twin.scenario import build, resolve_scenario

    try:
        ini = read_ini(args.ini)
    except CncConfigError as exc:
        raise BadInput(str(exc)) from None
    twin = ini.get("GANTRY_TWIN", {})
    try:
        period_s = float(ini.get("EMCMOT", {}).get("SERVO_PERIOD", SERVO_PERIOD_NS)) * 1e-9
        delay = int(twin.get("DELAY_PERIODS") or DELAY_PERIODS)
    except ValueError:
        raise BadInput(f"{args.ini}: [EMCMOT] SERVO_PERIOD or [GANTRY_TWIN] DELAY_PERIODS: not a number") from None
    try:
        LiveFifos.check()
    except LiveError as exc:
        raise BadInput(f"linuxcnc machine: {exc}") from None
    try:  # the loop is loaded or compiled below ("linuxcnc" is among the commands that compile nothing)
        check_cache_dir()
    except CacheDirError as exc:
        raise BadInput(str(exc)) from None
    telemetry = _telemetry(args.ini, twin.get("TELEMETRY", ""))
    path = resolve_scenario(twin.get("SCENARIO") or "no_load_circle")
    scenario = load_scenario(path, shlex.split(twin.get("SET", "")))
    d = DURATION_MAX_S  # the longest live run; LinuxCNC's exit or estop ends it before
    outputs = scenario.outputs.model_copy(update={"trace": False})  # the trace goes in parts (trace/)
    scenario = scenario.model_copy(update={"duration_s": d, "window_s": (0.0, d), "estimates_window_s": (0.0, d),
                                           "outputs": outputs})  # fmt: skip
    built = build(scenario, str(path))
    # The loop's kernel loaded (or compiled) before LinuxCNC's commands flow: the twin must keep their pace.
    simulate(built.plant, built.path, built.timing, built.controller, duration_s=2 * CHUNK_S, chunk_s=CHUNK_S)
    out = Path(twin["RUN_DIR"]) if twin.get("RUN_DIR") else new_run_dir(Path(twin.get("RUN_BASE") or RUNS_DIR))
    fifos = LiveFifos(delay)
    commands = LiveCommands(fifos, period_s)
    built = dataclasses.replace(built, path=commands, timing=TimingLaw(1.0))  # phi = t

    def say(text: str) -> None:  # to LinuxCNC's output and the run directory's log
        print(text, file=sys.stderr, flush=True)
        with contextlib.suppress(OSError), open(out / LIVE_LOG, "a", encoding="utf-8") as log:
            log.write(text + "\n")

    feedback = LiveFeedback(commands, built.plant, say)
    parts = TraceParts(out / "trace")
    alarms = _AlarmPrinter(built.monitor, say)
    views = [_LiveView(observer, commands) for observer in telemetry]
    try:
        with telemetry, RunWriter(out, built) as writer:
            try:
                fifos.start()
            except (LiveError, OSError) as exc:
                raise BadInput(f"the live link to LinuxCNC's HAL: {exc}") from None
            say(f"{PROG}: the twin is LinuxCNC's machine (pid {os.getpid()}); run directory {out}")
            outcome = writer.run([feedback, parts, alarms, *views], hold_s=CHUNK_S, chunk_s=CHUNK_S)
        if outcome.error is not None:
            feedback.set_fault(str(outcome.error))
    except BaseException as exc:
        if fifos.started:
            feedback.set_fault(f"the twin stopped: {type(exc).__name__}: {exc}")
        raise
    finally:
        parts.flush()
        fifos.close()
    info = commands.info()
    delay, cpu = info["delay_ms"], fifos.cpu
    measured = (
        f"feedback delay median {delay['median']:g} ms, p99 {delay['p99']:g} ms" if delay else "no delay measured"
    )
    load = f"; the twin's CPU {100 * cpu['cpu_fraction']:.1f} % of a core" if cpu else ""
    say(f"{PROG}: the twin followed LinuxCNC for {commands.duration_s:.3f} s ({commands.count} commands); ended by "
        f"{info['ended_by']}; {measured}{load}; results in {out}/")  # fmt: skip
    return EXIT_RUN_FAILED if feedback.fault is not None else EXIT_OK


def _telemetry(ini: Path, words: str):
    """The rerun observers the INI's ``[GANTRY_TWIN] TELEMETRY`` asks for (``--viewer``, ``--serve-web``,
    ``--save FILE.rrd``, ``--connect URL``); BadInput in one line for anything else."""
    from gantry_twin.cli.telemetry import add_telemetry_arguments, telemetry_observers

    parser = argparse.ArgumentParser(prog=f"{ini}: [GANTRY_TWIN] TELEMETRY", add_help=False, exit_on_error=False)
    add_telemetry_arguments(parser)
    try:
        parsed, unknown = parser.parse_known_args(shlex.split(words))
    except (argparse.ArgumentError, ValueError) as exc:
        raise BadInput(f"{ini}: [GANTRY_TWIN] TELEMETRY: {exc}") from None
    if unknown or parsed.realtime is not None:
        what = " ".join(unknown) or "--realtime"
        raise BadInput(f"{ini}: [GANTRY_TWIN] TELEMETRY: {what}: takes --viewer, --serve-web, --save, --connect")
    return telemetry_observers(parsed, out=sys.stderr)


class _LiveView:
    """A telemetry observer fed a live run: it sees the commands received so far as the path (it draws and
    measures against them as they come; a live run has no whole path when it starts)."""

    def __init__(self, inner, commands) -> None:
        self.inner, self.commands = inner, commands

    def watch(self, monitor) -> None:
        watch = getattr(self.inner, "watch", None)
        if callable(watch):
            watch(monitor)

    def on_start(self, run, trace) -> None:
        self.inner.on_start(dataclasses.replace(run, path=self.commands.held(), samples=2), trace)

    def on_chunk(self, trace, start: int, stop: int) -> None:
        self.inner.on_chunk(trace, start, stop)

    def on_end(self, trace) -> None:
        self.inner.on_end(trace)


class _AlarmPrinter:
    """An observer that says each new alarm of the scenario's health monitor as it is raised (on LinuxCNC's output
    and in the live run's log: readable after any kill), as the shadow monitor prints its own."""

    def __init__(self, monitor, say) -> None:
        self.monitor, self.say, self.seen = monitor, say, 0

    def on_start(self, run, trace) -> None:
        pass

    def on_chunk(self, trace, start: int, stop: int) -> None:
        if self.monitor is not None:
            for alarm in self.monitor.alarms[self.seen :]:
                self.say(f"{PROG}: alarm: {alarm.describe()}")
            self.seen = len(self.monitor.alarms)

    def on_end(self, trace) -> None:
        pass


def announce(scenario: object, wanted: bool) -> None:
    """With progress wanted: one line before LinuxCNC runs a part program (it runs at the wall clock's pace)."""
    contour = getattr(scenario, "contour", None)
    if wanted and isinstance(contour, GcodeSpec) and contour.cnc == "linuxcnc":
        print(f"{PROG}: LinuxCNC runs {contour.file} headless, in real time (docs/linuxcnc.md) ...", file=sys.stderr)
