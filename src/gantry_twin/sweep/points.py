"""A sweep's points: planned and checked on the driver, run on the workers.

A point is the sweep's scenario with ``--set`` style overrides: the sweep's
``set``, then one value of each swept field. It is loaded as ``gantry-twin
run --set ...`` loads it (the file read once, then, as
:func:`~gantry_twin.scenario.load_scenario` does,
:func:`~gantry_twin.scenario.apply_overrides` and
:func:`~gantry_twin.scenario.validate_data`) and built on the driver
before anything runs; the workers get
the *resolved* scenario (plain data, never MuJoCo objects), validate and
build it again, run it with :func:`gantry_twin.run.execute` and summarise
it with :func:`gantry_twin.run.summarise`, the code ``gantry-twin run``
uses: a row's contour rms equals that run's to the last bit.

Each point is keyed by a hash of its resolved scenario and the package
version; ``--resume`` runs the points whose key has no ``ok`` row.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import json
import math
import re
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from gantry_twin.metrics import axial_rms_um, max_abs_command_v
from gantry_twin.outputs.summary import RunSummary
from gantry_twin.plant.model import AXES
from gantry_twin.run import RUN_FILES, execute, package_version, summarise, write_run
from gantry_twin.scenario import ScenarioError, apply_overrides, build, read_scenario_file, validate_data
from gantry_twin.sweep.sampling import draws
from gantry_twin.sweep.spec import SweepSpec, scenario_path

#: Row statuses: the run finished / it raised (``error`` says why) / its worker died too often.
STATUS_OK = "ok"
STATUS_FAILED = "failed"


@dataclass(frozen=True)
class Point:
    """One run of a sweep: its place, its swept values and the resolved scenario the worker gets."""

    index: int
    key: str
    values: dict[str, Any]
    sample: int | None
    seed: int | None
    resolved: dict[str, Any] = field(repr=False)


@dataclass(frozen=True)
class Plan:
    """Every point of a sweep, checked; ``fields``: the swept field paths in column order."""

    spec: SweepSpec
    source: str
    scenario_source: str
    fields: tuple[str, ...]
    points: tuple[Point, ...]
    version: str


def override(field_path: str, value: Any) -> str:
    """``field=value`` as ``--set`` takes it; the value as YAML text that reads back as the same value."""
    if type(value) is int or (type(value) is float and _PLAIN_FLOAT.fullmatch(repr(value))):
        return f"{field_path}={value!r}"  # what safe_dump writes, without its cost (a sweep of 2000 points)
    text = yaml.safe_dump(value, default_flow_style=True, width=math.inf).strip()
    return f"{field_path}={text.removesuffix('...').strip()}"


#: A float whose repr YAML reads back as the same float (YAML 1.1 wants a dot and no bare exponent).
_PLAIN_FLOAT = re.compile(r"-?[0-9]+\.[0-9]+")


def point_key(resolved: dict[str, Any], version: str) -> str:
    """Hash of a resolved scenario and the package version (hex, 20 characters)."""
    text = json.dumps(resolved, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(f"{version}\n{text}".encode()).hexdigest()[:20]


def _combinations(spec: SweepSpec) -> list[tuple[dict[str, Any], int | None, int | None]]:
    """(swept values, random sample index, seed) of every point, in row order."""
    grid = [
        dict(zip([a.field for a in spec.axes], combo, strict=True))
        for combo in itertools.product(*(a.points() for a in spec.axes))
    ]
    samples: list[tuple[dict[str, Any], int | None]] = [({}, None)]
    if spec.random is not None:
        samples = [(drawn, i) for i, drawn in enumerate(draws(spec.random))]
    seeds: list[tuple[dict[str, Any], int | None]] = [({}, None)]
    if spec.repeats is not None:
        r = spec.repeats
        seeds = [({r.field: r.seed + i}, r.seed + i) for i in range(r.count)]
    return [({**g, **s, **rep}, sample, seed) for g in grid for s, sample in samples for rep, seed in seeds]


def _describe(values: dict[str, Any]) -> str:
    return ", ".join(f"{k}={override(k, v).partition('=')[2]}" for k, v in values.items())


@contextlib.contextmanager
def _at_point(source: str, index: int, values: dict[str, Any]) -> Iterator[None]:
    """A ScenarioError inside, said of the sweep file and the point (``point 3 (payload.mass_kg=5)``)."""
    try:
        yield
    except ScenarioError as exc:
        where = f"point {index} ({_describe(values)})"
        raise ScenarioError(source, where, f"{exc.field}: {exc.message}" if exc.field else exc.message) from None


def plan_sweep(spec: SweepSpec, source: str) -> Plan:
    """Every point, loaded, validated and built as ``gantry-twin run`` would: a ScenarioError names the point."""
    path = scenario_path(spec, source)
    base = read_scenario_file(path)  # then as load_scenario: overrides, validation, the file's stem as default name
    common = [override(k, v) for k, v in spec.set.items()]
    version = package_version()
    points: list[Point] = []
    seen: dict[str, int] = {}
    combinations, validated = _combinations(spec), []
    for index, (values, _, _) in enumerate(combinations):  # every point validated before any is built:
        with _at_point(source, index, values):  # a bad last point of many is found in milliseconds per point
            data = apply_overrides(base, [*common, *(override(k, v) for k, v in values.items())], str(path))
            validated.append(validate_data(data, str(path), default_name=path.stem))
    for index, ((values, sample, seed), scenario) in enumerate(zip(combinations, validated, strict=True)):
        with _at_point(source, index, values):
            build(scenario, str(path))
        resolved = scenario.resolved()
        key = point_key(resolved, version)
        if key in seen:
            where = f"point {index} ({_describe(values)})"
            raise ScenarioError(source, where, f"runs the same scenario as point {seen[key]}; each point must differ")
        seen[key] = index
        points.append(Point(index, key, values, sample, seed, resolved))
    fields = tuple(f for _, f in spec.swept())
    return Plan(spec, source, str(path), fields, tuple(points), version)


# ---------------------------------------------------------------------------
# On the worker.


@dataclass
class PointResult:
    """What a worker sends back: the row's metrics and status, and the run's files when ``keep_runs``."""

    row: dict[str, Any]
    files: dict[str, bytes] | None = None


def run_point(resolved: dict[str, Any], source: str, keep_runs: bool = False) -> PointResult:
    """Run one resolved scenario as ``gantry-twin run`` does; a run that raises gives a ``failed`` row."""
    from gantry_twin.sweep.engine import warm_up

    scenario = validate_data(resolved, source)
    built = build(scenario, source)
    warm_up(scenario, source)
    started = time.perf_counter()
    try:
        trace = execute(built)
    except Exception as exc:  # the run failed, not the sweep: recorded in the row
        return PointResult(failed_row(exc, time.perf_counter() - started))
    wall_time_s = time.perf_counter() - started
    files = None
    if keep_runs:
        with tempfile.TemporaryDirectory(prefix="gantry-twin-point-") as tmp:
            data = write_run(Path(tmp), built, trace, wall_time_s)
            files = {name: (Path(tmp) / name).read_bytes() for name in RUN_FILES if (Path(tmp) / name).is_file()}
    else:
        data = summarise(built, trace)  # what gantry-twin run's summary.json holds
    row = metrics_row(data, axial_rms_um(trace, scenario.metric_window_s), max_abs_command_v(trace))
    return PointResult({**row, "wall_time_s": wall_time_s, "status": STATUS_OK, "error": None}, files)


def metrics_row(summary: RunSummary, axial_um: Any, max_abs_u_v: Any) -> dict[str, Any]:
    """A row's metric columns from a run's summary and the metrics the summary lacks."""
    contour = summary.contour_error_um
    row: dict[str, Any] = {"contour_rms_um": contour.rms, "contour_max_um": contour.max}
    saturation = summary.saturation or {}
    for i, axis in enumerate(AXES):
        row[f"axial_rms_{axis}_um"] = float(axial_um[i])
        row[f"max_abs_u_{axis}_v"] = float(max_abs_u_v[i])
        row[f"saturated_fraction_{axis}"] = float(saturation[axis].fraction)
    for name, e in (summary.estimates or {}).items():
        row[f"estimate_{name}"], row[f"true_{name}"], row[f"error_pct_{name}"] = e.estimate, e.true, e.error_pct
        row[f"trustworthy_{name}"] = e.trustworthy  # DIARC only (gantry_twin.health.confidence)
    row["alarms"] = len(summary.health.alarms) if summary.health is not None else None
    return row


def failed_row(exc: BaseException, wall_time_s: float | None = None) -> dict[str, Any]:
    """The row of a point whose run raised (or whose worker died): status ``failed`` and one line of why."""
    message = str(exc).splitlines()[0] if str(exc) else ""
    return {"wall_time_s": wall_time_s, "status": STATUS_FAILED, "error": f"{type(exc).__name__}: {message}"}
