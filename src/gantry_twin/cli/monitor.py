"""``gantry-twin monitor --log LOG [SCENARIO]``: DIARC's estimator and the health monitor over a recorded log."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from gantry_twin.cli.common import PROG
from gantry_twin.compiling import replay_compile_notice
from gantry_twin.controllers import DIARC, create
from gantry_twin.health.log_monitor import ESTIMATE_WINDOW_S, monitor_log
from gantry_twin.outputs.files import atomic_write_text
from gantry_twin.outputs.summary import RunSummary, log_summary, summary_json
from gantry_twin.plant import Plant
from gantry_twin.scenario import apply_overrides, controller_options, load_scenario, make_monitor, validate_data
from gantry_twin.sysid.logs import read_log

#: A log's sample period may differ from the machine's by this fraction (the clock of a logger, rounding of t_s).
PERIOD_MATCH = 0.01
#: What a period this many times the machine's suggests t_s was written in.
_UNIT_GUESSES = ((1e3, "t_s looks like milliseconds"), (1e6, "t_s looks like microseconds"))


def check_sample_period(path: str, period_s: float, machine_s: float) -> None:
    """ValueError (exit 2) unless the log's sample period is the machine's (DIARC's estimator runs at that rate)."""
    if abs(period_s - machine_s) <= PERIOD_MATCH * machine_s:
        return
    ratio = period_s / machine_s
    guess = next((why for factor, why in _UNIT_GUESSES if abs(ratio / factor - 1.0) <= PERIOD_MATCH), "")
    raise ValueError(
        f"--log {path}: its sample period is {period_s:.6g} s (t_s in seconds), not the machine's "
        f"{machine_s * 1e3:g} ms" + (f": {guess}; give t_s in seconds" if guess else "; give a log sampled at it")
    )


def monitor_log_command(args: argparse.Namespace, scenario_path: Path | None, out: Path) -> RunSummary:
    """Run it, write out/summary.json, return it.

    The scenario (default: every field's default) gives DIARC's gains and
    estimator and the monitor's settings; ``--baseline`` a commissioning
    run's summary.json (as ``monitor.baseline_summary``). Raises LogError,
    ScenarioError or ValueError (bad input: exit 2).
    """
    overrides = ["monitor.enable=true", *args.overrides]
    if args.baseline is not None:
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
            f"monitor --log runs DIARC's estimator; the scenario's controller is {scenario.controller.name}"
        )
    monitor = make_monitor(scenario, controller, source)
    log = read_log(args.log)
    check_sample_period(args.log, log.sample_period_s, Plant().timestep_s)
    end = float(log.t_s[-1])
    lo, hi = scenario.monitor.baseline_window_s
    if scenario.monitor.baseline_summary is None and hi > end + 1e-9:
        raise ValueError(
            f"--log {args.log}: the log ends at {end:.4g} s, inside the monitor's baseline window [{lo:g}, {hi:g}] s, "
            "so nothing would be judged; give a longer log, --set monitor.baseline_window_s=[a,b] inside it, "
            "or --baseline SUMMARY (a healthy run's summary.json)"
        )
    replay_compile_notice(PROG)  # a line if the estimator's replay compiles first
    report = monitor_log(log, controller, monitor)
    summary = log_summary(log, report, (end - min(ESTIMATE_WINDOW_S, 0.5 * log.duration_s), end))
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "summary.json", summary_json(summary))
    return summary
