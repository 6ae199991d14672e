"""Throughput and overhead of the sweep engine (docs/performance.md, docs/sweeps.md).

    PYTHONPATH=src python benchmarks/bench_sweep.py [--points 16] [--duration 10] [--workers 1 2]

One sweep of ``--points`` DIARC runs of ``--duration`` simulated seconds
(the paper's circle, payload evenly from 0 to 15 kg) run by
:func:`gantry_twin.sweep.run_sweep` on a LocalCluster of each ``--workers``
count, into a temporary directory. For each it prints:

* startup: creating the cluster and warming the workers up (imports,
  loading the compiled loop; compiling it too when the cache is cold);
* points: from the first point submitted to the last row written, and the
  throughput, points per minute; the ratio of the last count's throughput
  to the first's;
* the run time of a point (its row's ``wall_time_s``: ``execute`` alone) and
  the engine's overhead per point: with one worker the points run back to
  back, so (points wall time - sum of the points' run times) / points is
  everything else a point costs: scheduling, sending the scenario and the
  row, building the run and summarising it on the worker, rewriting
  results.parquet. With more workers the same sum is taken over
  workers x wall time, so it also counts workers idle at the end.

Measure on a quiet machine: the load average before each sweep is printed.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import textwrap
import time
from pathlib import Path

import pyarrow.parquet as pq

from gantry_twin.sweep import Plan, load_sweep, plan_sweep, run_sweep
from gantry_twin.sweep.points import run_point

#: Acceptance: 2 workers give this much of 1 worker's throughput; the engine costs at most this share of a point.
RATIO_MIN = 1.8
OVERHEAD_MAX = 0.05


def sweep_file(directory: Path, points: int, duration_s: float) -> Path:
    path = directory / "bench.yaml"
    path.write_text(
        textwrap.dedent(
            f"""\
            scenario: no_load_circle
            set: {{duration_s: {duration_s}, window_s: [0.5, {duration_s}], estimates_window_s: [1, {duration_s}]}}
            axes:
              - {{field: payload.mass_kg, linspace: {{start: 0, stop: 15, num: {points}}}}}
            metrics: [contour, estimates]
            """
        )
    )
    return path


def point_cost_around_the_run(plan: Plan, repeats: int = 3) -> float:
    """Median of what run_point spends besides the simulation (validate, build, summarise), in this process, s."""
    point = plan.points[0]
    run_point(point.resolved, plan.scenario_source)  # compile or load the loop first
    costs = []
    for _ in range(repeats):
        started = time.perf_counter()
        result = run_point(point.resolved, plan.scenario_source)
        costs.append(time.perf_counter() - started - result.row["wall_time_s"])
    return sorted(costs)[len(costs) // 2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=16)
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds per point")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()

    print(f"{args.points} points of {args.duration:g} s, DIARC; {os.cpu_count()} cores")
    throughputs = []
    with tempfile.TemporaryDirectory(prefix="bench-sweep-") as tmp:
        path = sweep_file(Path(tmp), args.points, args.duration)
        plan = plan_sweep(load_sweep(path), str(path))
        around_s = point_cost_around_the_run(plan)
        for workers in args.workers:
            load = os.getloadavg()
            out = Path(tmp) / f"out{workers}"
            started = time.perf_counter()
            done = run_sweep(plan, out, workers=workers)
            total_s = time.perf_counter() - started
            run_s = [r["wall_time_s"] for r in pq.read_table(out / "results.parquet").to_pylist()]
            assert done.ran == len(run_s) == args.points and done.failed == 0
            mean_run = sum(run_s) / len(run_s)
            overhead = (done.points_s * workers - sum(run_s)) / args.points
            throughputs.append(args.points / done.points_s)
            print(
                f"\n{workers} worker{'s' if workers > 1 else ''} (load average before "
                f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}):\n"
                f"  startup {done.startup_s:6.1f} s   points {done.points_s:6.1f} s   whole call {total_s:6.1f} s\n"
                f"  throughput {60 * throughputs[-1]:6.1f} points/min\n"
                f"  run time per point {mean_run:.3f} s; overhead per point {1e3 * overhead:.1f} ms "
                f"= {100 * overhead / mean_run:.2f} % of it"
            )
            if workers == 1:
                verdict = "PASS" if overhead / mean_run < OVERHEAD_MAX else "FAIL"
                print(f"  engine overhead under {100 * OVERHEAD_MAX:g} % of a point: {verdict}")
                print(
                    f"  of it, validating, building and summarising a point (in this process): {1e3 * around_s:.1f} ms;"
                    f" scheduling, transfer, results.parquet: {1e3 * (overhead - around_s):.1f} ms"
                )
    if len(throughputs) > 1:
        ratio = throughputs[-1] / throughputs[0]
        verdict = "PASS" if ratio >= RATIO_MIN else "FAIL"
        print(
            f"\nthroughput {args.workers[-1]} vs {args.workers[0]} workers: x{ratio:.2f} (need {RATIO_MIN}): {verdict}"
        )


if __name__ == "__main__":
    main()
