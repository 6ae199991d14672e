"""Wall time of the paper's 16 runs of 30 s in parallel processes (issue 6, acceptance 2).

    PYTHONPATH=src python benchmarks/bench_report.py [--processes 2] [--duration 30] [--cold]

The runs of the paper's Tables 1-4: C1 DARC, C2 DIARC, C3 DRC on the circle
(2 rad/s) and the ellipse (3 rad/s) for Set 1 (no load), Set 2 (5 kg
payload) and Set 3 (+0.6 V on Y from 1.86 s to 4.86 s), C3 not on Set 3:
16 runs, paper settings, default sensing, ``on_path`` start. They are spread
over a ProcessPoolExecutor (spawned workers); the wall time covers starting
the workers, imports, loading the compiled kernels and every run.
``--cold`` first empties a private numba cache, so the figure includes
compiling the kernels (in each worker) and shows that cost separately.
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass


@dataclass(frozen=True)
class RunSpec:
    """One paper run: controller (darc, diarc, drc), contour, load set (1, 2, 3), duration s."""

    controller: str
    contour: str
    load_set: int
    duration_s: float


def paper_runs(duration_s: float) -> list[RunSpec]:
    """The 16 runs: 3 controllers x 2 contours x Sets 1-2, and DARC, DIARC on Set 3."""
    runs = []
    for load_set in (1, 2, 3):
        for contour in ("circle", "ellipse"):
            for controller in ("darc", "diarc", "drc"):
                if not (load_set == 3 and controller == "drc"):
                    runs.append(RunSpec(controller, contour, load_set, duration_s))
    return runs


def step_on_y(t):  # noqa: ANN001, ANN201
    """Set 3: +0.6 V on the Y input from 1.86 s to 4.86 s."""
    import numpy as np

    d = np.zeros((t.size, 2))
    d[(t >= 1.86) & (t < 4.86), 1] = 0.6
    return d


def run(spec: RunSpec) -> dict:
    """Run one spec; return its contour metrics over the last period and its times."""
    t0 = time.perf_counter()
    from gantry_twin import Payload, Plant, TimingLaw, circle, paper_ellipse, simulate
    from gantry_twin.controllers import create
    from gantry_twin.metrics import contour_metrics

    t1 = time.perf_counter()
    path, rate = (circle(), 2.0) if spec.contour == "circle" else (paper_ellipse(), 3.0)
    plant = Plant(Payload(5.0) if spec.load_set == 2 else None)
    disturbance = step_on_y if spec.load_set == 3 else None
    trace = simulate(plant, path, TimingLaw(rate), create(spec.controller), spec.duration_s, disturbance=disturbance)
    period = 2.0 * math.pi / rate
    m = contour_metrics(trace, (spec.duration_s - period, spec.duration_s))
    t2 = time.perf_counter()
    return {"spec": spec, "rms_um": m.rms_um, "max_um": m.max_um, "import_s": t1 - t0, "run_s": t2 - t1}


def run_all(specs: list[RunSpec], processes: int) -> tuple[float, list[dict]]:
    """Wall time of all specs over ``processes`` spawned workers, and the results in order."""
    t0 = time.perf_counter()
    with ProcessPoolExecutor(processes, mp_context=multiprocessing.get_context("spawn")) as pool:
        results = list(pool.map(run, specs))
    return time.perf_counter() - t0, results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--processes", type=int, default=2)
    parser.add_argument("--duration", type=float, default=30.0, help="simulated seconds per run")
    parser.add_argument("--cold", action="store_true", help="start from an empty numba cache (includes compiling)")
    args = parser.parse_args()
    specs = paper_runs(args.duration)
    with tempfile.TemporaryDirectory() as cache:
        if args.cold:
            os.environ["NUMBA_CACHE_DIR"] = cache  # inherited by the spawned workers
        wall, results = run_all(specs, args.processes)
    print(f"{'run':<28}{'rms um':>8}{'max um':>8}{'import+load s':>15}{'run s':>8}")
    for r in results:
        s = r["spec"]
        label = f"{s.controller} {s.contour} set {s.load_set}"
        print(f"{label:<28}{r['rms_um']:8.2f}{r['max_um']:8.2f}{r['import_s']:15.2f}{r['run_s']:8.2f}")
    total_run = sum(r["run_s"] for r in results)
    print(f"\n{len(specs)} runs of {args.duration:g} s on {args.processes} processes: wall {wall:.1f} s "
          f"({'empty numba cache: compiling included' if args.cold else 'compiled kernels loaded from the cache'}); "
          f"sum of run times {total_run:.1f} s, {len(specs) * args.duration / wall:.0f}x real time overall")


if __name__ == "__main__":
    main()
