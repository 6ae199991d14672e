"""Cost of the 0.2 ms loop against MuJoCo's own C loop (docs/performance.md).

    PYTHONPATH=src python benchmarks/bench_loop.py [--seconds 4] [--repeats 5]

Prints, from one run on one machine: us per step and real-time factor of
``mujoco.mj_step(m, d, nstep=N)`` (MuJoCo's C loop, the model at rest) and of
simulate() as a user calls it with the pd, DRC, DARC and DIARC controllers
and the example compiled plug-in of examples/gantry-example-pd (compiled
backend; DIARC also on the reference backend); each loop's ratio to the C
loop, and the plug-in's ratio to the built-in pd; numba's first-use compile
time (fresh cache) and cache-load time; the peak memory of a 60 s DIARC run
with full 5 kHz recording; the cost with the Coulomb and the LuGre plant side by
side with the rig plant's (``--friction-only``: that alone). Loops are measured interleaved, best of
``--repeats``, in wall time and in this thread's CPU time (less sensitive to
other processes on the machine): compare ratios, not absolute times.
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
from gantry_twin.controllers import available, create, register
from gantry_twin.friction import Friction

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SRC = os.path.join(ROOT, "src")
EXAMPLE_SRC = os.path.join(ROOT, "examples", "gantry-example-pd", "src")
CONTROLLERS = ("pd", "drc", "darc", "diarc", "example_pd")

_FIRST_USE = """
import time, json
t0 = time.perf_counter()
from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import create
from gantry_twin.contours import reference
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
from gantry_twin.contours import reference
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


#: The plants whose loop cost is compared: the paper's (Coulomb), the same with default LuGre friction, and the
#: shipped rig plant (models/rig.xml: LuGre, a static input offset and a force ripple; docs/rig-plant.md).
PLANTS = {
    "coulomb": lambda: Plant(),
    "lugre": lambda: Plant(friction=Friction(model="lugre")),
    "rig": lambda: Plant.shipped("rig"),
}


def bare_steps(n: int, friction: str = "coulomb") -> tuple[float, float]:
    """MuJoCo's C loop on the same model, from rest: n control samples (each plant.substeps physics steps)."""
    plant = PLANTS[friction]()
    plant.reset(np.zeros(2), np.zeros(2))
    return _timed(lambda: mujoco.mj_step(plant.model, plant.data, nstep=n * plant.substeps))


def _example_plugin() -> None:
    """Register the example plug-in if it is not installed (then it is imported from examples/)."""
    if "example_pd" in available():
        return
    sys.path.insert(0, EXAMPLE_SRC)
    from gantry_example_pd import ExamplePD

    register("example_pd", ExamplePD)


def loop(name: str, seconds: float, backend: str = "compiled", friction: str = "coulomb") -> tuple[float, float]:
    plant, controller = PLANTS[friction](), create(name)
    return _timed(lambda: simulate(plant, circle(), TimingLaw(2.0), controller, seconds, backend=backend))


def friction_costs(seconds: float, repeats: int, n: int) -> None:
    """The loop's cost per 0.2 ms sample with the Coulomb, the LuGre and the rig plant, side by side."""
    keys = ["mj_step C loop", "pd", "diarc"]
    results: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for name in keys[1:]:
        loop(name, 0.01, friction="rig")
    for _ in range(repeats):
        for model in PLANTS:
            results.setdefault((keys[0], model), []).append(bare_steps(n, model))
            for name in keys[1:]:
                results.setdefault((name, model), []).append(loop(name, seconds, friction=model))
    best = {key: min(c for _, c in v) / n * 1e6 for key, v in results.items()}
    lugre = Plant(friction=Friction(model="lugre"))
    print(
        f"\nfriction models, CPU us per 0.2 ms sample, best of {repeats} (lugre: {lugre.substeps} physics steps "
        f"per sample, integrator {mujoco.mjtIntegrator(lugre.model.opt.integrator).name})"
    )
    print(f"{'loop':<24}{'coulomb':>10}{'lugre':>10}{'rig':>10}{'lugre/coulomb':>15}{'rig/coulomb':>13}")
    for name in keys:
        c, g, r = best[(name, "coulomb")], best[(name, "lugre")], best[(name, "rig")]
        print(f"{name:<24}{c:10.2f}{g:10.2f}{r:10.2f}{g / c:15.2f}{r / c:13.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=4.0, help="simulated seconds per loop measurement")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--skip-memory", action="store_true")
    parser.add_argument("--friction-only", action="store_true", help="only the Coulomb / LuGre comparison")
    args = parser.parse_args()
    ts = 2e-4
    n = int(round(args.seconds / ts))

    if args.friction_only:
        friction_costs(args.seconds, args.repeats, n)
        return
    builtin = tuple(name for name in CONTROLLERS if name != "example_pd")
    with tempfile.TemporaryDirectory() as cache:
        cold = _child(_FIRST_USE.format(names=builtin), cache)
        warm = _child(_FIRST_USE.format(names=builtin), cache)
    print(
        f"numba, first use with an empty cache (compile all kernels): {cold['first_runs_s']:.1f} s "
        f"(import {cold['import_s']:.2f} s)"
    )
    print(
        f"numba, later processes (load from cache):                  {warm['first_runs_s']:.2f} s "
        f"(import {warm['import_s']:.2f} s)"
    )

    _example_plugin()
    for name in CONTROLLERS:  # load (or compile) every kernel before timing
        loop(name, 0.01)
    bare_key = "mj_step C loop"
    results: dict[str, list[tuple[float, float]]] = {bare_key: []}
    results.update({name: [] for name in CONTROLLERS})
    for _ in range(args.repeats):
        results[bare_key].append(bare_steps(n))
        for name in CONTROLLERS:
            results[name].append(loop(name, args.seconds))
    ref_seconds = min(0.5, args.seconds)
    results["diarc (reference)"] = [loop("diarc", ref_seconds, "reference")]
    steps = {key: (int(round(ref_seconds / ts)) if "reference" in key else n) for key in results}

    best = {
        key: (min(w for w, _ in v) / steps[key] * 1e6, min(c for _, c in v) / steps[key] * 1e6)
        for key, v in results.items()
    }
    bare_wall, bare_cpu = best[bare_key]
    print(
        f"\nloops of {args.seconds:g} s simulated ({n} steps), best of {args.repeats}; "
        f"simulate() with recording to memory and the derived errors, circle, default sensing"
    )
    print(f"{'loop':<24}{'us/step':>9}{'x C loop':>10}{'RT factor':>11}{'CPU us/step':>13}{'x C loop':>10}")
    for key, (wall, cpu) in best.items():
        label = key if key == bare_key or "reference" in key else f"{key} (compiled)"
        print(f"{label:<24}{wall:9.2f}{wall / bare_wall:10.2f}{200.0 / wall:11.1f}{cpu:13.2f}{cpu / bare_cpu:10.2f}")
    (pd_wall, pd_cpu), (ex_wall, ex_cpu) = best["pd"], best["example_pd"]
    print(
        f"\nDIARC / C loop: {best['diarc'][0] / bare_wall:.2f}x wall, {best['diarc'][1] / bare_cpu:.2f}x CPU "
        f"(target 1.4x); example plug-in / built-in pd: {ex_wall / pd_wall:.2f}x wall, {ex_cpu / pd_cpu:.2f}x CPU "
        f"(target 1.15x)"
    )

    friction_costs(args.seconds, args.repeats, n)

    if not args.skip_memory:
        mem = _child(_MEMORY)
        before, after = mem["rss_before_kb"] / 1e3, mem["rss_after_kb"] / 1e3
        print(
            f"\n60 s DIARC run, full 5 kHz recording ({mem['samples']} samples): trace arrays "
            f"{mem['trace_bytes'] / 1e6:.1f} MB; process peak RSS {before:.0f} MB before the run, "
            f"{after:.0f} MB after (+{after - before:.0f} MB)"
        )


if __name__ == "__main__":
    main()
