"""Cost of the 0.2 ms loop against a bare ``mujoco.mj_step`` (issue 6).

    PYTHONPATH=src python benchmarks/bench_loop.py [--seconds 4] [--repeats 5]

Prints, from one run on one machine: us per step and real-time factor of a
bare mj_step Python loop and of simulate() with the DRC, DARC, DIARC and pd
controllers (compiled backend; DIARC also on the reference backend), each
loop's ratio to the bare step; numba's first-use compile time (fresh cache)
and cache-load time; the peak memory of a 60 s DIARC run with full 5 kHz
recording. Loops are measured interleaved, best of ``--repeats``, in wall
time and in this thread's CPU time (less sensitive to other processes).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import mujoco
import numpy as np

from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import create
from gantry_twin.paths import reference

SRC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "src")
CONTROLLERS = ("pd", "drc", "darc", "diarc")

_FIRST_USE = """
import time, json
t0 = time.perf_counter()
from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import create
from gantry_twin.paths import reference
t1 = time.perf_counter()
for name in {names!r}:
    simulate(Plant(), circle(), TimingLaw(2.0), create(name), duration_s=0.01)
t2 = time.perf_counter()
print(json.dumps({{"import_s": t1 - t0, "first_runs_s": t2 - t1}}))
"""

_MEMORY = """
import json, resource
import numpy as np
from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import create
from gantry_twin.paths import reference
simulate(Plant(), circle(), TimingLaw(2.0), create("diarc"), duration_s=0.01)
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
trace = simulate(Plant(), circle(), TimingLaw(2.0), create("diarc"), duration_s=60.0)
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
arrays = [v for v in vars(trace).values() if isinstance(v, np.ndarray)] + list(trace.controller_state.values())
print(json.dumps({"rss_before_kb": before, "rss_after_kb": after, "trace_bytes": sum(a.nbytes for a in arrays),
                  "samples": int(trace.t_s.size)}))
"""


def _child(code: str, cache_dir: str | None = None) -> dict:
    env = dict(os.environ, PYTHONPATH=SRC + os.pathsep + os.environ.get("PYTHONPATH", ""))
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = cache_dir
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _timed(fn) -> tuple[float, float]:  # noqa: ANN001
    w0, c0 = time.perf_counter(), time.thread_time()
    fn()
    return time.perf_counter() - w0, time.thread_time() - c0


def bare_steps(n: int) -> tuple[float, float]:
    plant = Plant()
    plant.reset(np.zeros(2), np.zeros(2))
    model, data = plant.model, plant.data

    def run() -> None:
        for _ in range(n):
            mujoco.mj_step(model, data)

    return _timed(run)


def loop(name: str, seconds: float, backend: str = "compiled") -> tuple[float, float]:
    plant, controller = Plant(), create(name)
    return _timed(lambda: simulate(plant, circle(), TimingLaw(2.0), controller, seconds, backend=backend))


def derived_errors_cost(seconds: float) -> float:
    """Seconds simulate() spends on e, eps_n and the true eps_c (paths.contour_error) per chunk of 0.1 s."""
    finish = sys.modules["gantry_twin.simulate"]._finish_chunk
    path, timing = circle(), TimingLaw(2.0)
    trace = simulate(Plant(), path, timing, create("pd"), seconds)
    ref = reference(path, timing, trace.t_s)
    chunk = 500
    t0 = time.perf_counter()
    for start in range(0, trace.t_s.size, chunk):
        finish(trace, ref, path, start, min(trace.t_s.size, start + chunk))
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=4.0, help="simulated seconds per loop measurement")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--skip-memory", action="store_true")
    args = parser.parse_args()
    ts = 2e-4
    n = int(round(args.seconds / ts))

    with tempfile.TemporaryDirectory() as cache:
        cold = _child(_FIRST_USE.format(names=CONTROLLERS), cache)
        warm = _child(_FIRST_USE.format(names=CONTROLLERS), cache)
    print(f"numba, first use with an empty cache (compile all kernels): {cold['first_runs_s']:.1f} s "
          f"(import {cold['import_s']:.2f} s)")
    print(f"numba, later processes (load from cache):                  {warm['first_runs_s']:.2f} s "
          f"(import {warm['import_s']:.2f} s)")

    for name in CONTROLLERS:  # load every kernel before timing
        loop(name, 0.01)
    results: dict[str, list[tuple[float, float]]] = {"bare mj_step": []}
    results.update({name: [] for name in CONTROLLERS})
    for _ in range(args.repeats):
        results["bare mj_step"].append(bare_steps(n))
        for name in CONTROLLERS:
            results[name].append(loop(name, args.seconds))
    derived = min(derived_errors_cost(args.seconds) for _ in range(args.repeats)) / n * 1e6
    ref_seconds = min(0.5, args.seconds)
    results["diarc (reference)"] = [loop("diarc", ref_seconds, "reference")]
    steps = {key: (int(round(ref_seconds / ts)) if "reference" in key else n) for key in results}

    best = {key: (min(w for w, _ in v) / steps[key] * 1e6, min(c for _, c in v) / steps[key] * 1e6)
            for key, v in results.items()}  # fmt: skip
    bare_wall, bare_cpu = best["bare mj_step"]
    print(f"\nloops of {args.seconds:g} s simulated ({n} steps), best of {args.repeats}; "
          f"simulate() with recording to memory, circle, default sensing")
    print(f"{'loop':<20}{'us/step':>9}{'x bare':>8}{'RT factor':>11}{'CPU us/step':>13}{'x bare':>8}"
          f"{'loop w/o eps_c':>16}{'x bare':>8}")
    for key, (wall, cpu) in best.items():
        label = key if key == "bare mj_step" or "reference" in key else f"{key} (compiled)"
        row = f"{label:<20}{wall:9.2f}{wall / bare_wall:8.2f}{200.0 / wall:11.1f}{cpu:13.2f}{cpu / bare_cpu:8.2f}"
        if key in CONTROLLERS:
            row += f"{wall - derived:16.2f}{(wall - derived) / bare_wall:8.2f}"
        print(row)
    print(f"(derived errors e, eps_n and the true contour error eps_c, computed per 0.1 s chunk with numpy: "
          f"{derived:.2f} us/step; 'loop w/o eps_c' = measure, control, record, mj_step)")

    if not args.skip_memory:
        mem = _child(_MEMORY)
        before, after = mem["rss_before_kb"] / 1e3, mem["rss_after_kb"] / 1e3
        print(f"\n60 s DIARC run, full 5 kHz recording ({mem['samples']} samples): trace arrays "
              f"{mem['trace_bytes'] / 1e6:.1f} MB; process peak RSS {before:.0f} MB before the run, "
              f"{after:.0f} MB after (+{after - before:.0f} MB)")


if __name__ == "__main__":
    main()
