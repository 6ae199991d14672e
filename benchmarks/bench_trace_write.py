"""Size and write time of trace.parquet for each storage choice (docs/performance.md).

    PYTHONPATH=src python benchmarks/bench_trace_write.py [--duration 30] [--scenario no_load_circle] [--repeats 5]

Simulates one run in memory (DIARC on the scenario, full 5 kHz), builds its table as
:func:`gantry_twin.outputs.tracefile.trace_table` does (float64 time and positions, float32 the rest) and as
before the compact trace (every column float64), then writes it once per choice below into a temporary
file, one row group per 10 s of the run as ``gantry-twin run`` writes it, and prints the file's
size and the best of ``--repeats`` write times (``pq.write_table`` on the ready table; building
the table is timed once, apart). The row marked ``*`` is the shipped choice
(``TRACE_PARQUET_OPTIONS``); the ratio of its write time to the old writer's is printed last.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from gantry_twin.outputs import tracefile as results
from gantry_twin.outputs.files import PARQUET_OPTIONS
from gantry_twin.outputs.tracefile import TRACE_PARQUET_OPTIONS, trace_table

BSS = {"column_encoding": "BYTE_STREAM_SPLIT"}
#: (label, all float64?, writer options); the first is the writer before the compact trace, the shipped one is marked.
CHOICES: list[tuple[str, bool, dict[str, Any]]] = [
    ("float64, snappy (before)", True, PARQUET_OPTIONS),
    ("float64, snappy, dictionary pages (older)", True, {}),
    ("float64, zstd", True, {**PARQUET_OPTIONS, "compression": "zstd"}),
    ("float64, zstd, BYTE_STREAM_SPLIT", True, {**PARQUET_OPTIONS, "compression": "zstd", **BSS}),
    ("mixed, snappy", False, PARQUET_OPTIONS),
    ("mixed, snappy, BYTE_STREAM_SPLIT", False, {**PARQUET_OPTIONS, **BSS}),
    ("mixed, zstd", False, {**PARQUET_OPTIONS, "compression": "zstd"}),
    ("mixed, zstd, BYTE_STREAM_SPLIT", False, TRACE_PARQUET_OPTIONS),
    ("mixed, zstd level 3, BYTE_STREAM_SPLIT", False, {**TRACE_PARQUET_OPTIONS, "compression_level": 3}),
    ("mixed, zstd level 9, BYTE_STREAM_SPLIT", False, {**TRACE_PARQUET_OPTIONS, "compression_level": 9}),
    ("mixed, zstd, dictionary pages", False, {"compression": "zstd"}),
]
#: Row-group lengths tried with the shipped options, s of the run (10 s: what `gantry-twin run` writes).
ROW_GROUPS_S = (1.0, 10.0, 30.0)


#: Significant bits (of float32's 24) kept by :func:`rounded`, to show what a lossy choice would give.
LOSSY_BITS = (16, 12)


def rounded(table: pa.Table, bits: int) -> pa.Table:
    """The table with each float32 column rounded (to nearest even) to ``bits`` significant bits."""
    drop = np.uint32(24 - bits)
    columns = {}
    for field in table.schema:
        values = table.column(field.name).to_numpy()
        if field.type == pa.float32():
            raw = values.view(np.uint32)
            half = np.uint32((1 << int(drop - 1)) - 1) + ((raw >> drop) & np.uint32(1))
            values = (((raw + half) >> drop) << drop).view(np.float32)
        columns[field.name] = values
    return pa.table(columns, metadata=table.schema.metadata)


def simulated_trace(scenario: str, duration_s: float):
    from gantry_twin.run import execute
    from gantry_twin.scenario import build, load_scenario, resolve_scenario

    return execute(build(load_scenario(resolve_scenario(scenario), [f"duration_s={duration_s:g}"])))


def write_once(table: pa.Table, path: Path, rows_per_group: int, options: dict[str, Any]) -> float:
    """Wall time of one write, s."""
    started = time.perf_counter()
    pq.write_table(table, path, row_group_size=rows_per_group, **options)
    return time.perf_counter() - started


def measure(table: pa.Table, rows_per_group: int, options: dict[str, Any], repeats: int) -> tuple[float, float]:
    """(file MB, best write time s)."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "trace.parquet"
        best = min(write_once(table, path, rows_per_group, options) for _ in range(repeats))
        return path.stat().st_size / 1e6, best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=30.0, help="simulated seconds (default 30)")
    parser.add_argument("--scenario", default="no_load_circle", help="shipped scenario or file (no_load_circle)")
    parser.add_argument("--repeats", type=int, default=5, help="writes per choice; the best time is kept")
    args = parser.parse_args()

    trace = simulated_trace(args.scenario, args.duration)
    started = time.perf_counter()
    mixed = trace_table(trace)
    build_s = time.perf_counter() - started
    with mock.patch.object(results, "stored_dtype", lambda column: np.float64):  # the table before the compact trace
        float64 = results.trace_table(trace)
    per_s = round(1.0 / trace.sample_period_s)
    rows_10s = 10 * per_s
    print(f"{args.scenario}, DIARC, {args.duration:g} s: {mixed.num_rows} rows x {mixed.num_columns} columns")
    print(f"  trace_table (float64 time and positions, float32 the rest): {build_s:.3f} s")
    print(f"  {'choice':<52} {'MB':>7} {'write s':>8}")
    times = {}
    for label, all_float64, options in CHOICES:
        size, seconds = measure(float64 if all_float64 else mixed, rows_10s, options, args.repeats)
        times[label] = seconds
        mark = "*" if options is TRACE_PARQUET_OPTIONS else " "
        print(f"{mark} {label:<52} {size:7.2f} {seconds:8.3f}")
    for group_s in ROW_GROUPS_S:
        size, seconds = measure(mixed, int(group_s * per_s), TRACE_PARQUET_OPTIONS, args.repeats)
        print(f"  {f'shipped options, row groups of {group_s:g} s':<52} {size:7.2f} {seconds:8.3f}")
    all32 = mixed.cast(
        pa.schema(
            [f.with_type(pa.float64() if f.name == "t_s" else pa.float32()) for f in mixed.schema],
            metadata=mixed.schema.metadata,
        )
    )
    size, seconds = measure(all32, rows_10s, TRACE_PARQUET_OPTIONS, args.repeats)
    print(f"  {'shipped options, positions float32 too (not shipped)':<52} {size:7.2f} {seconds:8.3f}")
    for bits in LOSSY_BITS:
        size, seconds = measure(rounded(mixed, bits), rows_10s, TRACE_PARQUET_OPTIONS, args.repeats)
        label = f"float32 columns kept to {bits} bits (lossy, not shipped)"
        print(f"  {label:<52} {size:7.2f} {seconds:8.3f}")
    before, after = times[CHOICES[0][0]], times["mixed, zstd, BYTE_STREAM_SPLIT"]
    print(f"write time, shipped / before: {after / before:.2f} ({after:.3f} s / {before:.3f} s)")


if __name__ == "__main__":
    main()
