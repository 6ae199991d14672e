"""The runs under ``runs/`` (``gantry-twin runs``): each run directory with its size, status and time, and which
ones a prune that keeps the last N per scenario would remove (docs/cli.md, "runs")."""

from __future__ import annotations

import calendar
import json
import os
import re
import time
from dataclasses import dataclass
from pathlib import Path

from gantry_twin.inputs import read_input_file
from gantry_twin.outputs.rundirs import LATEST, STAMP_FORMAT, resolve_run

#: A run directory's name: ``<UTC time>-<six hex digits>`` (gantry_twin.outputs.rundirs).
RUN_NAME = re.compile(r"^\d{8}T\d{6}Z-[0-9a-f]{6}$")


@dataclass(frozen=True)
class RunEntry:
    """One run directory: its scenario (the parent's name), path, size in bytes, status and start time."""

    scenario: str
    path: Path
    size_bytes: int
    status: str  # "ok", "failed" (summary.json's status), "compare" (compare's output) or "incomplete" (neither)
    started_s: float
    latest: bool  # the scenario's ``latest`` names it


def _size(path: Path) -> int:
    total = 0
    for root, _, files in os.walk(path):
        for name in files:
            try:
                total += os.lstat(os.path.join(root, name)).st_size
            except OSError:
                pass
    return total


def _status(run_dir: Path) -> str:
    if not (run_dir / "summary.json").exists() and (run_dir / "compare.json").is_file():
        return "compare"  # gantry-twin compare's output (runs/compare/<UTC time>-<id>/): not a run, not a broken one
    try:
        text = read_input_file(run_dir / "summary.json", "a run's summary.json")  # a FIFO or /dev/zero: refused
        return str(json.loads(text).get("status", "incomplete"))
    except (OSError, ValueError, AttributeError, RecursionError):  # ValueError: InputFileError and bad JSON too
        return "incomplete"


def _latest_target(scenario_dir: Path) -> Path | None:
    if not (scenario_dir / LATEST).exists():
        return None
    try:
        return resolve_run(scenario_dir / LATEST).resolve()
    except (OSError, ValueError):  # ValueError: a ``latest`` text file that names no run (InputFileError)
        return None


def list_runs(runs_dir: Path) -> list[RunEntry]:
    """Every run directory ``runs_dir/<scenario>/<UTC time>-<id>``, by scenario then time."""
    entries = []
    for scenario_dir in sorted(p for p in Path(runs_dir).iterdir() if p.is_dir() and not p.is_symlink()):
        target = _latest_target(scenario_dir)
        for run in sorted(p for p in scenario_dir.iterdir() if RUN_NAME.match(p.name) and p.is_dir()):
            started = calendar.timegm(time.strptime(run.name.split("-")[0], STAMP_FORMAT))
            entries.append(RunEntry(scenario_dir.name, run, _size(run), _status(run), started, run.resolve() == target))
    return entries


def to_prune(entries: list[RunEntry], keep: int) -> list[RunEntry]:
    """The runs beyond the last ``keep`` of each scenario; never a ``latest`` target."""
    doomed = []
    by_scenario: dict[str, list[RunEntry]] = {}
    for e in entries:
        by_scenario.setdefault(e.scenario, []).append(e)
    for runs in by_scenario.values():
        runs = sorted(runs, key=lambda e: e.path.name)
        old = runs[: max(len(runs) - keep, 0)]
        doomed.extend(e for e in old if not e.latest)
    return doomed


def human_size(n: int) -> str:
    """``12.3 MB`` (powers of 1000)."""
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} GB"


def describe(e: RunEntry) -> str:
    """One line: ``<scenario>/<dir>  <size>  <status>  <UTC time>`` and ``(latest)``."""
    when = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(e.started_s))
    mark = "  (latest)" if e.latest else ""
    return f"{e.scenario}/{e.path.name}  {human_size(e.size_bytes):>9}  {e.status:<10}  {when}{mark}"
