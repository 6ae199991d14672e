"""Peak memory of a long run with the full trace (the target: a 3600 s run under 1.5 GB; docs/performance.md).

    PYTHONPATH=src python benchmarks/bench_long_run.py [--duration 3600] [--scenario no_load_circle] [--keep DIR]

Runs ``gantry-twin run SCENARIO --set duration_s=DURATION --no-progress`` in a child process (the
command line, which holds 10 s of the run in memory and streams the trace to trace.parquet) and
prints its wall time, its peak resident memory (the kernel's ru_maxrss of the child), the trace's
size on disk against the size announced before the run, and its row groups. The trace goes to a
temporary directory (about 4 GB for 3600 s), removed afterwards unless ``--keep DIR`` is given.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: The acceptance bound for a 3600 s run with the full trace.
TARGET_RSS_MB = 1500.0


def run(scenario: str, duration_s: float, out: Path) -> tuple[int, float, float, str]:
    """(exit code, wall s, peak RSS MB, stderr) of one ``gantry-twin run`` in a child process."""
    command = [sys.executable, "-m", "gantry_twin.cli", "run", scenario, "--set", f"duration_s={duration_s:g}"]
    command += ["--no-progress", "--out", str(out)]
    started = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - started
    err = child.stderr.read() if child.stderr else ""
    child.returncode = os.waitstatus_to_exitcode(status)
    return child.returncode, wall, usage.ru_maxrss / 1024.0, err  # ru_maxrss: KiB on Linux


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=3600.0, help="simulated seconds (default 3600)")
    parser.add_argument("--scenario", default="no_load_circle", help="shipped scenario or file (no_load_circle)")
    parser.add_argument("--keep", type=Path, default=None, metavar="DIR", help="write the run here and keep it")
    args = parser.parse_args()

    import pyarrow.parquet as pq

    from gantry_twin.run import trace_size
    from gantry_twin.scenario import build, load_scenario, resolve_scenario

    built = build(load_scenario(resolve_scenario(args.scenario), [f"duration_s={args.duration:g}"]))
    size = trace_size(built)
    with tempfile.TemporaryDirectory() as folder:
        out = args.keep or Path(folder) / "run"
        code, wall, rss_mb, err = run(args.scenario, args.duration, out)
        if code != 0:
            raise SystemExit(f"the run failed (exit {code}): {err.strip()}")
        trace = out / "trace.parquet"
        meta = pq.ParquetFile(trace).metadata
        on_disk = trace.stat().st_size
    verdict = "ok" if rss_mb < TARGET_RSS_MB else "OVER"
    print(f"{args.scenario}, {args.duration:g} s, full trace ({size.samples} samples x {size.columns} columns)")
    print(f"  wall time      : {wall:8.1f} s")
    print(f"  peak RSS       : {rss_mb:8.1f} MB (target < {TARGET_RSS_MB:g} MB): {verdict}")
    print(f"  trace.parquet  : {on_disk / 1e6:8.1f} MB ({meta.num_rows} rows, {meta.num_row_groups} row groups)")
    print(f"  announced size : {size.bytes / 1e6:8.1f} MB (before compression: {size.row_bytes} bytes a row)")
    for line in err.strip().splitlines():
        print(f"  stderr: {line}")


if __name__ == "__main__":
    main()
