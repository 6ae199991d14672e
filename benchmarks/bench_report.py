"""Wall time of the paper's 16 runs of 30 s in parallel processes (target 20 s; docs/performance.md).

    PYTHONPATH=src python benchmarks/bench_report.py [--processes 2] [--duration 30] [--cold]

The runs of the paper's Tables 1-4, as ``gantry-twin report`` runs them
(:func:`gantry_twin.reports.paper.paper_matrix`: the shipped scenarios, C1 DARC,
C2 DIARC, C3 DRC on the circle and the ellipse for Sets 1-3, C3 not on Set 3;
16 runs, contour metrics over the scenarios' windows, the report's: each row
prints its window). ``--duration`` other
than 30 must leave room for those windows (Set 3's end at 6.5 s). The runs
are spread over a ProcessPoolExecutor (spawned workers); the wall time
covers starting the workers, imports, loading the compiled kernels and
every run.
``--cold`` first empties a private numba cache, so the figure includes
compiling the kernels (in each worker) and shows that cost separately.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import astuple
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the workers import the package inside run(), where it is timed
    from gantry_twin.reports.paper import Case

#: The paper's own columns (the report adds C2r, DIARC with the recommended estimator).
PAPER_LABELS = ("C1", "C2", "C3")


def run(fields: tuple) -> dict:
    """Run one case of the report's matrix (its fields: a Case would import the package when unpickled)."""
    t0 = time.perf_counter()
    from gantry_twin.reports.paper import Case, run_case

    t1 = time.perf_counter()
    case = Case(*fields)
    result = run_case(case)
    t2 = time.perf_counter()
    return {
        "case": case,
        "rms_um": result.rms_um,
        "max_um": result.max_um,
        "window_s": result.window_s,
        "import_s": t1 - t0,
        "run_s": t2 - t1,
    }


def run_all(cases: list[Case], processes: int) -> tuple[float, list[dict]]:
    """Wall time of all cases over ``processes`` spawned workers, and the results in order."""
    t0 = time.perf_counter()
    with ProcessPoolExecutor(processes, mp_context=multiprocessing.get_context("spawn")) as pool:
        results = list(pool.map(run, [astuple(case) for case in cases]))
    return time.perf_counter() - t0, results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--processes", type=int, default=2)
    parser.add_argument("--duration", type=float, default=30.0, help="simulated seconds per run")
    parser.add_argument("--cold", action="store_true", help="start from an empty numba cache (includes compiling)")
    args = parser.parse_args()
    from gantry_twin.reports.paper import paper_matrix

    cases = paper_matrix([f"duration_s={args.duration:g}"], labels=PAPER_LABELS)
    with tempfile.TemporaryDirectory() as cache:
        if args.cold:
            os.environ["NUMBA_CACHE_DIR"] = cache  # inherited by the spawned workers
        wall, results = run_all(cases, args.processes)
    print(
        "rms and max of abs(eps_c) over each run's window_s, the windows of gantry-twin report's Tables 1-2 "
        "(report.run_case: Sets 1-2 the second period [T, 2T], Set 3 [1.5, 6.5] s)"
    )
    print(f"{'run':<28}{'window_s (s)':>16}{'rms um':>8}{'max um':>8}{'import+load s':>15}{'run s':>8}")
    for r in results:
        c = r["case"]
        label = f"{c.controller} {c.contour} set {c.set_id}"
        window = f"[{r['window_s'][0]:.2f}, {r['window_s'][1]:.2f}]"
        print(f"{label:<28}{window:>16}{r['rms_um']:8.2f}{r['max_um']:8.2f}{r['import_s']:15.2f}{r['run_s']:8.2f}")
    total_run = sum(r["run_s"] for r in results)
    print(
        f"\n{len(cases)} runs of {args.duration:g} s on {args.processes} processes: wall {wall:.1f} s "
        f"({'empty numba cache: compiling included' if args.cold else 'compiled kernels loaded from the cache'}); "
        f"sum of run times {total_run:.1f} s, {len(cases) * args.duration / wall:.0f}x real time overall"
    )


if __name__ == "__main__":
    main()
