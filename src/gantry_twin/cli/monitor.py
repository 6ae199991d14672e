"""``gantry-twin monitor --log LOG [SCENARIO]``: DIARC's estimator and the health monitor over a recorded log."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TextIO

from gantry_twin.cli.common import PROG
from gantry_twin.controllers import DIARC, create
from gantry_twin.health.estimator_replay import estimator_replay
from gantry_twin.health.log_monitor import monitor_log
from gantry_twin.loop.compiling import compile_message
from gantry_twin.numerics.jit import is_cached
from gantry_twin.outputs.files import atomic_write_text
from gantry_twin.outputs.summary import RunSummary, log_summary, summary_json
from gantry_twin.outputs.tracefile import TRACE_FILE
from gantry_twin.plant.model import Plant
from gantry_twin.run import SCENARIO_FILE
from gantry_twin.scenario import apply_overrides, controller_options, load_scenario, make_monitor, validate_data
from gantry_twin.sysid.logs import check_sample_period, log_chunks, scan_log


def replay_compile_notice(prog: str, stream: TextIO | None = None) -> bool:
    """``monitor --log``: print the compile line if the estimator's replay kernel will compile first; True if so."""
    if is_cached(estimator_replay):
        return False
    print(compile_message(prog).replace("the 0.2 ms loop", "the estimator's replay"), file=stream or sys.stderr)
    return True


def run_log(log: Path, scenario: Path | None) -> tuple[Path, Path | None, str]:
    """``--log LOG [SCENARIO]``: the log file, the scenario that gives the settings, and a note saying where they
    came from ("" when SCENARIO was given or there is none to find).

    A twin run's directory is its trace.parquet; a log with a scenario.yaml beside it (a run's trace) is
    monitored with that run's own settings (its DIARC and monitor), so that the log gives the run's alarms,
    unless SCENARIO names other settings.
    """
    if log.is_dir() and (log / TRACE_FILE).is_file():
        log = log / TRACE_FILE
    beside = log.parent / SCENARIO_FILE
    if scenario is not None or log.name != TRACE_FILE or not beside.is_file():
        return log, scenario, ""
    return log, beside, f"{PROG}: monitor --log {log}: the run's own settings, from {beside}"


def monitor_settings(args: argparse.Namespace, scenario_path: Path | None, what: str) -> tuple:
    """The scenario (default: every field's default), DIARC with its gains and estimator, and the health monitor
    with its settings, for ``monitor --log`` and ``monitor --opcua`` (``what``); ``--baseline`` a commissioning
    run's summary.json (as ``monitor.baseline_summary``). ValueError if the controller is not DIARC."""
    overrides = ["monitor.enable=true", *args.overrides]
    if getattr(args, "baseline", None) is not None:
        overrides.append(f"monitor.baseline_summary={json.dumps(str(Path(args.baseline).resolve()))}")
    if scenario_path is not None:
        source = str(scenario_path)
        scenario = load_scenario(scenario_path, overrides, args.controller)
    else:
        source = "<defaults>"
        data = {"controller": {"name": args.controller}} if args.controller else {}
        scenario = validate_data(apply_overrides(data, overrides, source), source, "log")
    controller = create(scenario.controller.name, **controller_options(scenario, source))
    if not isinstance(controller, DIARC):
        raise ValueError(
            f"monitor {what} runs DIARC's estimator; the scenario's controller is {scenario.controller.name}"
        )
    return scenario, controller, make_monitor(scenario, controller, source)


def monitor_log_command(args: argparse.Namespace, scenario_path: Path | None, out: Path) -> RunSummary:
    """Run it, write out/summary.json, return it.

    The scenario (default: every field's default) gives DIARC's gains and
    estimator and the monitor's settings; ``--baseline`` a commissioning
    run's summary.json (as ``monitor.baseline_summary``). Raises LogError,
    ScenarioError or ValueError (bad input: exit 2).
    """
    scenario, controller, monitor = monitor_settings(args, scenario_path, "--log")
    log = scan_log(args.log)  # checked whole before the replay, a chunk at a time; then read again, likewise
    check_sample_period(f"--log {args.log}", log.sample_period_s, Plant().timestep_s)
    end = log.t_last_s - log.t_first_s  # the monitor's windows count from the log's first sample
    lo, hi = scenario.monitor.baseline_window_s
    if scenario.monitor.baseline_summary is None and hi > end + 1e-9:
        late = "" if log.t_first_s == 0.0 else f" after its first sample (t = {log.t_first_s:.6g} s)"
        raise ValueError(
            f"--log {args.log}: the log ends at {end:.4g} s{late}, inside the monitor's baseline window "
            f"[{lo:g}, {hi:g}] s, so nothing would be judged; give a longer log, --set monitor.baseline_window_s=[a,b] "
            "inside it, or --baseline SUMMARY (a healthy run's summary.json)"
        )
    replay_compile_notice(PROG)  # a line if the estimator's replay compiles first
    tally = monitor_log(log, log_chunks(args.log), controller, monitor)
    summary = log_summary(log, tally)
    try:
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / "summary.json", summary_json(summary))
    except OSError as exc:
        raise ValueError(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    return summary
