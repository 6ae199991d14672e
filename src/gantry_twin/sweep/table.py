"""``results.parquet``: one row per point, rewritten (atomically) as each point finishes.

Columns, in order: ``point`` (the point's index in the sweep), ``key`` (hash
of its resolved scenario and the package version), ``sample`` (index of its
random draw), ``seed`` (the repeat's seed), one column per swept field named
by its field path (``payload.mass_kg``), the kept metrics, ``wall_time_s``
(of the run itself), ``status`` (``ok``/``failed``), ``error`` and
``finished_utc``. Every write replaces the whole file through a temporary
file and a rename (:func:`gantry_twin.outputs.files.write_parquet`), so the file
on disk is always a valid table of the points finished so far: a killed
sweep loses only the points in flight.

The file's metadata (``gantry_twin_sweep``) holds the sweep file's name, its spec and its plan key
(:func:`plan_key`, a hash of every point's key): ``--resume`` takes only a file of the same plan.
"""

from __future__ import annotations

import hashlib
import json
import math
import numbers
import time
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from gantry_twin.outputs.files import write_parquet
from gantry_twin.scenario import ScenarioError
from gantry_twin.sweep.points import STATUS_OK, Plan, Point

RESULTS_FILE = "results.parquet"
_IDENTITY = [("point", pa.int64()), ("key", pa.string()), ("sample", pa.int64()), ("seed", pa.int64())]
_TAIL = [("wall_time_s", pa.float64()), ("status", pa.string()), ("error", pa.string()), ("finished_utc", pa.string())]


#: The key of the table's metadata that holds the sweep.
METADATA_KEY = "gantry_twin_sweep"


def plan_key(plan: Plan) -> str:
    """A hash of the plan: of every point's key (each a hash of its resolved scenario and the version), in order."""
    return hashlib.sha256("\n".join(p.key for p in plan.points).encode()).hexdigest()[:20]


def earlier_sweep(path: Path) -> dict[str, Any]:
    """What the results file at ``path`` says of the sweep that wrote it (``{}`` if it says nothing readable)."""
    try:
        metadata = pq.read_schema(path).metadata or {}
        found = json.loads(metadata.get(METADATA_KEY.encode(), b"{}"))
    except (OSError, pa.ArrowInvalid, ValueError):
        return {}
    return found if isinstance(found, dict) else {}


def _value_type(values: list[Any]) -> pa.DataType:
    """A swept field's column type: bool, int64, float64, else string (other values as JSON text)."""
    if all(isinstance(v, bool) for v in values):
        return pa.bool_()
    if all(isinstance(v, numbers.Integral) and not isinstance(v, bool) for v in values):
        return pa.int64()
    if all(isinstance(v, numbers.Real) and not isinstance(v, bool) for v in values):
        return pa.float64()
    return pa.string()


def _metric_type(metric: str) -> pa.DataType:
    if metric == "alarms":
        return pa.int64()
    return pa.bool_() if metric.startswith("trustworthy_") else pa.float64()


def _cell(value: Any, kind: pa.DataType) -> Any:
    if kind == pa.string() and not isinstance(value, str):
        return json.dumps(value)
    return value


class ResultsTable:
    """The rows of a sweep by point key, and the file they are written to."""

    def __init__(self, plan: Plan, path: Path) -> None:
        self.plan = plan
        self.path = Path(path)
        self.metrics = plan.spec.kept_metrics()
        self.field_types = {f: _value_type([p.values[f] for p in plan.points]) for f in plan.fields}
        metric_types = [(m, _metric_type(m)) for m in self.metrics]
        self.schema = pa.schema([*_IDENTITY, *self.field_types.items(), *metric_types, *_TAIL]).with_metadata(
            {
                METADATA_KEY: json.dumps(
                    {
                        "version": plan.version,
                        "source": plan.source,
                        "plan_key": plan_key(plan),
                        "spec": plan.spec.model_dump(mode="json"),
                    }
                )
            }
        )
        self.rows: dict[str, dict[str, Any]] = {}
        self._points = {p.key: p for p in plan.points}

    def load(self) -> int:
        """Take the rows of an earlier run of this sweep (the same plan key) from the file; returns how many are
        ``ok``. ScenarioError (exit 2, nothing changed) when the file holds another plan's results. (A killed
        driver's temporaries, and only those of a process that is gone, are removed by ``run_sweep``.)"""
        if not self.path.is_file():
            return 0
        earlier = earlier_sweep(self.path).get("plan_key")
        if earlier != plan_key(self.plan):
            what = f"plan {earlier}" if isinstance(earlier, str) else "no plan key"
            raise ScenarioError(
                str(self.path),
                "",
                f"holds the results of another sweep ({what}; {Path(self.plan.source).name} is plan "
                f"{plan_key(self.plan)}): nothing resumed; choose a new --out, or add --fresh to replace them",
            )
        try:
            old = pq.read_table(self.path).to_pylist()
        except (OSError, pa.ArrowInvalid) as exc:
            raise ScenarioError(
                str(self.path), "", f"cannot read it to resume ({exc}); remove it or choose another --out"
            ) from None
        for row in old:
            point = self._points.get(row.get("key"))
            if point is not None:
                self.rows[point.key] = {**row, **self._identity(point)}
        return sum(1 for row in self.rows.values() if row.get("status") == STATUS_OK)

    def done(self, point: Point) -> bool:
        return self.rows.get(point.key, {}).get("status") == STATUS_OK

    def _identity(self, point: Point) -> dict[str, Any]:
        cells = {f: _cell(point.values[f], self.field_types[f]) for f in self.plan.fields}
        return {"point": point.index, "key": point.key, "sample": point.sample, "seed": point.seed, **cells}

    def add(self, point: Point, row: dict[str, Any]) -> None:
        """Record a finished point and rewrite the file."""
        finished = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        self.rows[point.key] = {**row, **self._identity(point), "finished_utc": finished}
        self.write()

    def table(self) -> pa.Table:
        ordered = sorted(self.rows.values(), key=lambda r: r["point"])
        columns = {name: [_nan_to_none(r.get(name)) for r in ordered] for name in self.schema.names}
        return pa.table(columns, schema=self.schema)

    def write(self) -> None:
        write_parquet(self.path, self.table())


def _nan_to_none(value: Any) -> Any:
    return None if isinstance(value, float) and math.isnan(value) else value
