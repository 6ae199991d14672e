"""Running a built scenario and writing its outputs (used by the CLI, the report and sweeps)."""

from __future__ import annotations

import json
import platform
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gantry_twin.scenario import BuiltRun, dump_yaml
from gantry_twin.simulate import simulate
from gantry_twin.trace import Observer, Trace

#: The files :func:`write_run` leaves in a run's directory (docs/cli.md); summary.json is written last.
SUMMARY_FILE = "summary.json"
SCENARIO_FILE = "scenario.yaml"
TRACE_FILE = "trace.parquet"
RUN_INFO_FILE = "run_info.json"
RUN_FILES = (SUMMARY_FILE, SCENARIO_FILE, TRACE_FILE, RUN_INFO_FILE)


def execute(built: BuiltRun, observers: Sequence[Observer] = ()) -> Trace:
    """Simulate a built scenario."""
    s = built.scenario
    if built.monitor is not None:
        # First, so that observers after it (telemetry) see this chunk's alarms.
        observers = [built.monitor, *observers]
        for observer in observers:
            if hasattr(observer, "watch"):
                observer.watch(built.monitor)
    return simulate(
        built.plant,
        built.path,
        built.timing,
        built.controller,
        duration_s=s.duration_s,
        sensing=built.sensing,
        disturbance=built.disturbance,
        observers=observers,
        controller_name=s.controller.name,
        changes=built.changes,
    )


def write_run(out: Path, built: BuiltRun, trace: Trace, wall_time_s: float) -> dict[str, Any]:
    """Write scenario.yaml, trace.parquet, run_info.json and (last) summary.json into ``out``.

    A stale summary.json is removed first: summary.json present means the
    other files of that run are complete.
    """
    from gantry_twin.results import atomic_write_text, summary, summary_json, trace_table, write_parquet

    scenario = built.scenario
    health = built.monitor.report() if built.monitor is not None else None
    data = summary(scenario, trace, scenario.controller.name, health)
    out.mkdir(parents=True, exist_ok=True)
    (out / SUMMARY_FILE).unlink(missing_ok=True)
    if scenario.outputs.trace:
        write_parquet(out / TRACE_FILE, trace_table(trace, scenario.outputs.trace_stride))
    atomic_write_text(out / SCENARIO_FILE, dump_yaml(scenario.resolved()))
    atomic_write_text(out / RUN_INFO_FILE, json.dumps(_run_info(wall_time_s), indent=2) + "\n")
    atomic_write_text(out / SUMMARY_FILE, summary_json(data))
    return data


def package_version() -> str:
    """The installed gantry-twin's version ("unknown" when run from a source tree that is not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("gantry-twin")
    except PackageNotFoundError:
        return "unknown"


def _run_info(wall_time_s: float) -> dict[str, Any]:
    """What differs between two runs of the same scenario (kept out of summary.json)."""
    import mujoco

    return {
        "wall_time_s": wall_time_s,
        "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "gantry_twin": package_version(),
        "mujoco": mujoco.__version__,
        "python": platform.python_version(),
        "machine": platform.machine(),
    }
