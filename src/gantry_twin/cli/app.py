"""The command line: ``gantry-twin run | monitor | validate | report | sweep | scenarios | sweeps | export | compare |
identify | excite | fmu`` (docs/cli.md, docs/sweeps.md, docs/logs.md, docs/fmi.md).

Exit codes: 0 success; 2 bad input (one line on stderr naming the file, the
field and what is allowed; nothing written), an output directory that
cannot be written included; 1 the run itself failed (a fault in the run:
its trace up to the fault and summary.json with ``status: failed`` are
written); 3 ``monitor --fail-on-alarm`` and the health monitor raised an
alarm; 4 ``--strict`` (run, monitor) and a carriage touched an end stop (the
files are written; checked before 3); 128 + the signal's number when stopped
by a signal: 130 SIGINT (Ctrl-C), 143 SIGTERM, 129 SIGHUP.

SIGINT, SIGTERM and SIGHUP are handled alike: the first raises
:class:`Interrupted` (a KeyboardInterrupt) wherever the program is, which
removes the run's temporary files and stops the web viewer's process; later
ones are ignored while that happens. While ``--serve-web`` keeps serving a
finished run, one of them stops it (exit status of the run).
"""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import io
import os
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

from gantry_twin.cli import calibrate as calibrate_command
from gantry_twin.cli import compare as compare_command
from gantry_twin.cli import compile as compile_command
from gantry_twin.cli import excite as excite_command
from gantry_twin.cli import export as export_command
from gantry_twin.cli import fmu as fmu_command
from gantry_twin.cli import identify as identify_command
from gantry_twin.cli import linuxcnc as linuxcnc_command
from gantry_twin.cli import program as program_command
from gantry_twin.cli import report as report_command
from gantry_twin.cli import runs as runs_command
from gantry_twin.cli import serve as serve_command
from gantry_twin.cli import shadow as shadow_command
from gantry_twin.cli import sweep as sweep_command
from gantry_twin.cli import tune as tune_command
from gantry_twin.cli.common import (  # noqa: F401 -- the exit codes: tests and callers take them from here
    DEFAULT_SCENARIO,
    EXIT_ALARM,
    EXIT_BAD_INPUT,
    EXIT_END_STOP,
    EXIT_INTERRUPTED,
    EXIT_NOT_JUDGED,
    EXIT_OK,
    EXIT_RUN_FAILED,
    PROG,
    RUNS_DIR,
    BadInput,
    checked_out,
    failed,
    out_dir,
    scenario_path,
    writable_out,
)
from gantry_twin.cli.printing import format_health, format_summary, touched_end_stop, travel_warnings
from gantry_twin.cli.progress import ProgressBar, add_progress_arguments, progress_bar, progress_wanted  # noqa: F401 -- ProgressBar: tests
from gantry_twin.cli.telemetry import add_telemetry_arguments, telemetry_observers
from gantry_twin.cnc.session import LinuxCncError
from gantry_twin.controllers import available
from gantry_twin.loop.compiling import compile_notice
from gantry_twin.numerics.jit import CacheDirError, check_cache_dir
from gantry_twin.outputs.export import ExportError
from gantry_twin.outputs.rundirs import LATEST, new_run_dir, point_latest
from gantry_twin.outputs.signals import stop_signals_interrupt
from gantry_twin.reports.compare import CompareError
from gantry_twin.run import LARGE_TRACE_BYTES, RunWriter, package_version, trace_size
from gantry_twin.scenario import (
    ScenarioError,
    build,
    load_scenario,
    shipped,
)
from gantry_twin.scenario.listing import listing
from gantry_twin.settings import shorten
from gantry_twin.sysid.logs import LogError
from gantry_twin.telemetry import TelemetryError

#: The examples under ``gantry-twin --help`` (docs/cli.md has every command).
EXAMPLES = """examples:
  gantry-twin run                                   the paper's no-load circle with DIARC (30 s)
  gantry-twin run load_5kg_ellipse --controller darc --set duration_s=10
  gantry-twin run --set plant.model=paper           the same circle on the paper's ideal model
  gantry-twin scenarios                             the shipped scenarios
  gantry-twin sweeps                                the shipped sweeps
  gantry-twin compare runs/no_load_circle/<time>-<id> runs/no_load_circle/latest
  gantry-twin report --out runs/report              the paper's Tables 1-4 and figures
  gantry-twin monitor friction_drift_circle --fail-on-alarm
  gantry-twin sweep payload_0_20kg --workers 2
  gantry-twin compile                               compile the loops ahead of a first run

docs: docs/cli.md (every command, exit codes), docs/scenarios.md (every field)."""
#: File names ``run`` takes as a G-code part program rather than a scenario.
PROGRAM_SUFFIXES = program_command.PROGRAM_SUFFIXES
#: The scenario ``run`` uses when none is given.
#: Where outputs go by default: RUNS_DIR/<scenario name>/, RUNS_DIR/report/.


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit code 2."""

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {shorten(message, 200)} (see {self.prog} --help)", file=sys.stderr)
        raise SystemExit(EXIT_BAD_INPUT)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog=PROG,
        description="MuJoCo digital twin of a biaxial linear-motor gantry (Hu, Yao, Wang, Automatica 2010).",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {package_version()}")
    sub = parser.add_subparsers(
        dest="command",
        required=True,
        metavar="{run,monitor,validate,report,sweep,calibrate,tune,scenarios,sweeps,runs,export,compare,identify,excite,compile,serve,fmu,linuxcnc}",
        parser_class=_Parser,
    )

    run = sub.add_parser("run", help="run a scenario and write its results")
    run.set_defaults(func=_run)
    run.add_argument(
        "scenario",
        nargs="?",
        help=f"scenario YAML file or shipped scenario name ({PROG} scenarios lists them; default: {DEFAULT_SCENARIO})",
    )
    _add_controller(run)
    _add_set(run)
    _add_out(run)
    _add_plots(run)
    _add_strict(run)
    program_command.add_arguments(run)
    fmu_command.add_log_argument(run)
    fmu_command.add_limit_arguments(run)
    add_progress_arguments(run)
    add_telemetry_arguments(run)

    monitor = sub.add_parser("monitor", help="run a scenario with the health monitor and report its alarms")
    monitor.set_defaults(func=_monitor)
    monitor.add_argument(
        "scenario", nargs="?", help=f"scenario YAML file or shipped scenario name ({PROG} scenarios lists them)"
    )
    monitor.add_argument("--log", metavar="LOG", help="monitor a recorded log instead of a run (docs/logs.md)")
    monitor.add_argument(
        "--baseline", metavar="SUMMARY", help="with --log or --opcua: a healthy run's summary.json (no baseline window)"
    )
    _add_controller(monitor)
    _add_set(monitor)
    _add_out(monitor)
    _add_plots(monitor)
    monitor.add_argument(
        "--fail-on-alarm", action="store_true", help=f"exit with status {EXIT_ALARM} if the monitor raised any alarm"
    )
    _add_strict(monitor)
    fmu_command.add_log_argument(monitor)
    fmu_command.add_limit_arguments(monitor)
    add_progress_arguments(monitor)
    add_telemetry_arguments(monitor)
    shadow_command.add_arguments(monitor)

    validate = sub.add_parser("validate", help="check scenario files or read and plan part programs, without running")
    validate.set_defaults(func=_validate)
    validate.add_argument("scenario", nargs="+", help="scenario YAML file(s) or part programs (.ngc .nc .gcode)")
    _add_controller(validate)
    _add_set(validate)
    program_command.add_arguments(validate)

    report = sub.add_parser("report", help="run the paper's matrix and write a Markdown report with figures")
    report_command.add_arguments(report, RUNS_DIR)
    _add_set(report, "override a field in every scenario of the matrix, e.g. duration_s=10")
    report.set_defaults(func=report_command.command)

    identify = sub.add_parser("identify", help="identify M, B, Af (and LuGre) from logs; a plant file and a fit report")
    identify_command.add_arguments(identify)
    identify.set_defaults(func=identify_command.command)
    excite = sub.add_parser("excite", help="write an identification trajectory and run it on the twin")
    excite_command.add_arguments(excite)
    excite.set_defaults(func=excite_command.command)

    sweep = sub.add_parser("sweep", help="run a sweep or Monte Carlo study on a Dask cluster (docs/sweeps.md)")
    sweep_command.add_arguments(sweep, RUNS_DIR)
    sweep.set_defaults(func=sweep_command.command)
    calibrate = sub.add_parser("calibrate", help="fit the plant to a machine's measured contour errors")
    calibrate_command.add_arguments(calibrate)
    calibrate.set_defaults(func=calibrate_command.command)
    tune_command.register(sub)
    linuxcnc_command.register(sub)

    scenarios = sub.add_parser("scenarios", help="list the shipped scenarios, one line each")
    scenarios.set_defaults(func=_scenarios)
    sweeps = sub.add_parser("sweeps", help="list the shipped sweeps, one line each")
    sweeps.set_defaults(func=_sweeps)
    runs = sub.add_parser("runs", help="list the runs under runs/ (size, status, time); --prune --keep N")
    runs_command.add_arguments(runs, RUNS_DIR)
    runs.set_defaults(func=runs_command.command)
    export = sub.add_parser("export", help="write a run's trace as CSV (docs/cli.md)")
    export_command.add_arguments(export)
    export.set_defaults(func=export_command.command)
    compare = sub.add_parser("compare", help="the figures of runs side by side, and their plots overlaid")
    compare_command.add_arguments(compare, RUNS_DIR)
    compare.set_defaults(func=compare_command.command)
    serve = sub.add_parser("serve", help="run a scenario and serve it as a machine over OPC UA")
    serve_command.add_arguments(serve)
    _add_controller(serve)
    _add_set(serve)
    serve.set_defaults(func=serve_command.command)
    compile_parser = sub.add_parser("compile", help="compile the loops for this install before a first run")
    compile_command.add_arguments(compile_parser, DEFAULT_SCENARIO)
    compile_parser.set_defaults(func=compile_command.command)
    fmu_command.register(sub)
    return parser


def _add_controller(parser: argparse.ArgumentParser) -> None:
    names = ", ".join(available())  # registered and entry-point names; no plug-in is imported
    parser.add_argument("--controller", metavar="NAME", help=f"controller to use instead of the scenario's: {names}")


def _add_out(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out",
        metavar="DIR",
        type=Path,
        help=f"output directory (default: a new {RUNS_DIR}/<scenario name>/<UTC time>-<id>/, "
        f"{RUNS_DIR}/<scenario name>/latest names the last complete run)",
    )


def _add_plots(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--plots",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="draw the run's figures into DIR/plots/ (default: on; --no-plots to skip)",
    )
    parser.add_argument(
        "--plot-format", choices=("png", "svg", "pdf"), default="png", help="the figures' file format (default: png)"
    )
    parser.add_argument(
        "--plot-dpi", metavar="DPI", type=_positive_dpi, default=150.0, help="png resolution (default: 150 dpi)"
    )


def _positive_dpi(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of dots per inch, got {text!r}") from None
    if not 10.0 <= value <= 1200.0:
        raise argparse.ArgumentTypeError(f"must be in [10, 1200] dpi, got {text}")
    return value


def _add_strict(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--strict", action="store_true", help=f"exit with status {EXIT_END_STOP} if a carriage touched an end stop"
    )


def _add_set(parser: argparse.ArgumentParser, text: str = "override one scenario field (value parsed as YAML)") -> None:
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help=text)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``gantry-twin`` console script; returns the exit code."""
    if argv is None:  # the command line: a crash in compiled code (numba, MuJoCo) prints the Python stacks
        with contextlib.suppress(AttributeError, ValueError, io.UnsupportedOperation):
            faulthandler.enable()
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help (0) or a usage error (2)
        return int(exc.code or 0)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # the command line, for a report's provenance
    try:
        with stop_signals_interrupt():
            if args.command not in COMPILES_NOTHING and not getattr(args, "no_run", False):
                _check_kernel_cache()
            return args.func(args)
    except (ScenarioError, BadInput, TelemetryError, ExportError, CompareError, LogError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        print(f"{PROG}: interrupted ({signal.Signals(signum).name})", file=sys.stderr)
        return EXIT_INTERRUPTED + signum


#: The commands that call no compiled kernel (every other one may compile, or load, the loops: the cache is
#: checked before it starts). ``excite --no-run`` runs nothing either.
COMPILES_NOTHING = ("validate", "scenarios", "sweeps", "runs", "export", "compare", "linuxcnc")


def _check_kernel_cache() -> None:
    """The compiled-kernel cache can be made and written (numerics.jit.check_cache_dir), once, before any work:
    BadInput naming NUMBA_CACHE_DIR otherwise (numba would fall back, silently, to a folder beside the sources,
    and a sweep's workers would fail each point)."""
    try:
        check_cache_dir()
    except CacheDirError as exc:
        raise BadInput(str(exc)) from None


def _scenarios(args: argparse.Namespace) -> int:
    print("\n".join(listing()))
    return EXIT_OK


def _sweeps(args: argparse.Namespace) -> int:
    from gantry_twin.sweep.listing import listing as sweep_listing

    print("\n".join(sweep_listing()))
    return EXIT_OK


def _monitor(args: argparse.Namespace) -> int:
    """``monitor``: a scenario run with the health monitor, or (``--log``) the monitor over a recorded log."""
    if args.opcua is not None:
        if args.log is not None:
            raise BadInput("monitor: --log or --opcua, not both")
        return shadow_command.command(args, format_health)
    return _monitor_log(args) if args.log is not None else _run(args)


def _validate(args: argparse.Namespace) -> int:
    for arg in args.scenario:
        if program_command.is_program(arg):
            program_command.validate_program(Path(arg), args)
            continue
        name = str(scenario_path(arg))
        scenario = load_scenario(name, [*program_command.overrides(args, None), *args.overrides], args.controller)
        build(scenario, name)
        print(f"{name}: ok ({scenario.controller.name}, {scenario.contour.type}, {scenario.duration_s:g} s)")
    return EXIT_OK


def _writer(out: Path, built: Any, args: argparse.Namespace) -> RunWriter:
    """The run's writer: BadInput (exit 2) if ``out`` cannot be made or written, before anything runs."""
    try:
        return RunWriter(
            out,
            built,
            args.overrides,
            args.controller,
            plots=args.plots,
            plot_format=args.plot_format,
            plot_dpi=args.plot_dpi,
        )
    except OSError as exc:
        raise BadInput(f"--out {out}: cannot write there ({exc.strerror or exc})") from None


def _announce_large_trace(built: Any) -> None:
    """One line on stderr before a run whose trace.parquet would pass LARGE_TRACE_BYTES."""
    size = trace_size(built)
    if size.bytes > LARGE_TRACE_BYTES:
        stride = size.stride_under()
        print(
            f"{PROG}: note: trace.parquet will take up to {size.bytes / 1e9:.1f} GB ({size.rows} samples x "
            f"{size.columns} columns, before compression); --set outputs.trace_stride={stride} keeps one sample "
            f"in {stride} (up to {size._replace(stride=stride).bytes / 1e9:.2f} GB), outputs.trace=false none",
            file=sys.stderr,
            flush=True,
        )


def _monitor_log(args: argparse.Namespace) -> int:
    """``monitor --log``: DIARC's estimator and the health monitor over a log (gantry_twin.health.log_monitor)."""
    from gantry_twin.cli.monitor import monitor_log_command, run_log

    scenario = None if args.scenario is None else scenario_path(args.scenario)
    log, scenario, note = run_log(Path(args.log), scenario)
    args.log = str(log)
    if note:
        print(note, file=sys.stderr, flush=True)
    # runs never overwrite: a new directory under runs/<log>-monitor/ unless --out names one (outputs.rundirs)
    out = (
        checked_out(args.out)
        if args.out is not None
        else new_run_dir(checked_out(RUNS_DIR / f"{Path(args.log).stem}-monitor"))
    )
    try:
        with writable_out(out):  # before the replay compiles and runs; removed again, empty, on bad input
            data = monitor_log_command(args, scenario, out)
    except ValueError as exc:
        raise BadInput(str(exc).splitlines()[0]) from None
    if args.out is None:
        point_latest(out)
    print("\n".join([*format_health(data.health), f"results in {out}/ (summary.json)"]), flush=True)
    if not data.health.judged:
        return _judged_nothing(out)
    return EXIT_ALARM if args.fail_on_alarm and data.health.alarms else EXIT_OK


def _judged_nothing(out: Path) -> int:
    print(
        f"{PROG}: monitor judged nothing: every parameter stayed in its baseline window or was never excited "
        f"enough to judge (health.judged is empty in {out}/summary.json); not a healthy verdict",
        file=sys.stderr,
    )
    return EXIT_NOT_JUDGED


def _run(args: argparse.Namespace) -> int:
    if args.scenario is None and args.command == "monitor":
        raise BadInput("monitor: give a SCENARIO to run, or --log LOG")
    if getattr(args, "baseline", None) is not None:
        raise BadInput(
            "--baseline: only with --log or --opcua (a scenario names its baseline in monitor.baseline_summary)"
        )
    path = scenario_path(args.scenario)
    overrides = list(args.overrides)
    program = None
    if path.suffix.lower() in PROGRAM_SUFFIXES:  # a part program runs in the default scenario (docs/gcode.md)
        program, path = path.resolve(), shipped(DEFAULT_SCENARIO)
    overrides[:0] = program_command.overrides(args, program)
    if args.command == "monitor":
        overrides.insert(0, "monitor.enable=true")
    scenario = fmu_command.with_logged_variables(
        load_scenario(path, overrides, args.controller), args.log_fmu_variables
    )
    scenario = fmu_command.with_limits(scenario, args.fmu_timeout, args.fmu_memory)
    linuxcnc_command.announce(scenario, progress_wanted(args))
    try:
        built = build(scenario, str(path))
    except ScenarioError as exc:
        if program is not None and exc.field == "contour.file":
            raise BadInput(exc.message) from None  # FILE:LINE: WORD: what is wrong
        raise
    except LinuxCncError as exc:  # LinuxCNC could not run the program: not the user's input
        print(f"{PROG}: run failed: {exc}", file=sys.stderr)
        return EXIT_RUN_FAILED
    out = out_dir(args.out, scenario)
    with _writer(out, built, args) as writer:
        telemetry = telemetry_observers(args)  # checks every option before anything runs
        with telemetry:  # at once: an interrupt from here on removes --save's temporary
            _announce_large_trace(built)
            notice = compile_notice(built.controller, PROG)  # a line, and seconds, if the loop compiles first
            try:
                outcome = writer.run([notice, progress_bar(args), *telemetry])
            except Exception as exc:  # the run or the writing failed: not the user's input
                return failed("run", exc)
            if outcome.failed:
                if os.environ.get("GANTRY_TWIN_DEBUG") and outcome.error is not None:
                    raise outcome.error
                failure = outcome.summary.failure
                print(
                    f"{PROG}: run failed: {failure.error}; the run up to it is in {out}/ "
                    f"({', '.join(outcome.files)}; status: failed)",
                    file=sys.stderr,
                )
                return EXIT_RUN_FAILED
            if args.out is None:
                _point_latest(out)
            if telemetry.rerun_observer is not None:  # the dashboard's estimates marked as summary.json judges them
                estimates = outcome.summary.estimates or {}
                telemetry.rerun_observer.mark_estimates({n: e.distrust for n, e in estimates.items() if e.distrust})
            print(format_summary(outcome.summary, outcome.wall_time_s, out, outcome.files), flush=True)
    if telemetry.recording_failed is not None:  # e.g. a full disk: the run's files are complete, the recording not
        print(f"{PROG}: {telemetry.recording_failed}; the run's results are in {out}/", file=sys.stderr)
        return EXIT_RUN_FAILED
    if (note := fmu_command.python_loop_note(built.controller, outcome.summary.steps, outcome.wall_time_s)) is not None:
        print(note, file=sys.stderr)
    if writer.plots_skipped is not None:
        print(f"{PROG}: note: no plots: {writer.plots_skipped}", file=sys.stderr)
    for line in travel_warnings(outcome.summary):
        print(f"{PROG}: warning: {line}", file=sys.stderr)
    if args.strict and touched_end_stop(outcome.summary):
        return EXIT_END_STOP
    health = outcome.summary.health
    if args.command == "monitor" and health is not None and not health.judged:
        return _judged_nothing(out)
    if getattr(args, "fail_on_alarm", False) and health is not None and health.alarms:
        return EXIT_ALARM
    return EXIT_OK


def _point_latest(out: Path) -> None:
    """runs/<name>/latest -> this run (a warning if it cannot be: the run itself is complete)."""
    try:
        point_latest(out)
    except OSError as exc:
        print(f"{PROG}: warning: {out.parent / LATEST} not updated ({exc.strerror or exc})", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
