"""Cost of the 0.2 ms loop against MuJoCo's C rollout of the same physics, and the compile (docs/performance.md).

    PYTHONPATH=src python benchmarks/bench_loop.py [--seconds 4] [--repeats 5]

Prints, from one run on one machine:

* numba's compile, each in a fresh process with an empty cache: the loops of
  all four built-in controllers (pd, drc, darc, diarc), and a single DIARC
  run; then the load of all four from the filled cache. CPU seconds
  (``time.process_time``, all threads) and wall.
* the README's first ``gantry-twin run`` (the default scenario) from an empty
  cache against a second run: CPU seconds of the child process (user + sys,
  all threads, ``os.wait4``) and wall (``--skip-first-run``: leave it out).
* The loop's floor: for each controller, the closed loop's own commands
  (motor volts and disturbance, as recorded) replayed from its initial state
  with ``mujoco.rollout`` (MuJoCo's C loop, one thread), which steps the same
  physics through the same states; the replay's positions are checked to
  equal the trace's. Beside it, for history, ``mj_step(m, d, nstep=N)`` with
  the model at rest (stuck dry friction, cheaper).
* simulate() as a user calls it with pd, DRC, DARC, DIARC and the example
  compiled plug-in of examples/gantry-example-pd (compiled backend; DIARC
  also on the reference backend): us per step in wall time and in process
  CPU time (all threads: a BLAS pool woken by the loop would show here), and
  each loop's ratio to the rollout of its own commands.
* the peak memory of a 60 s DIARC run with full 5 kHz recording; the cost
  with the Coulomb, the LuGre and the rig plant side by side
  (``--friction-only``: that alone).

Loops are measured interleaved, the median of ``--repeats``: compare ratios,
not absolute times (the machine may be shared; the load average is printed
before and after). The CPU that threads other than the loop's take during
the measurements is counted apart (/proc/self/task) and printed.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import mujoco
import numpy as np
from mujoco import rollout

from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import available, create, register
from gantry_twin.plant.friction import Friction

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SRC = os.path.join(ROOT, "src")
EXAMPLE_SRC = os.path.join(ROOT, "examples", "gantry-example-pd", "src")
CONTROLLERS = ("pd", "drc", "darc", "diarc", "example_pd")

_FIRST_USE = """
import time, json
w0, c0 = time.perf_counter(), time.process_time()
from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import create
w1, c1 = time.perf_counter(), time.process_time()
for name in {names!r}:
    simulate(Plant(), circle(), TimingLaw(2.0), create(name), duration_s=0.01)
w2, c2 = time.perf_counter(), time.process_time()
print(json.dumps({{"import_s": c1 - c0, "first_runs_cpu_s": c2 - c1, "first_runs_wall_s": w2 - w1}}))
"""

_MEMORY = """
import json, resource
import numpy as np
from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import create
from gantry_twin.paths.contours import reference
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


def _threads_cpu_s() -> dict[int, float]:
    """CPU s (user + sys) of each thread of this process so far, from /proc/self/task/*/stat (Linux; {} elsewhere)."""
    found = {}
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    try:
        tasks = os.listdir("/proc/self/task")
    except OSError:
        return found
    for task in tasks:
        try:
            with open(f"/proc/self/task/{task}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        found[int(task)] = (int(fields[11]) + int(fields[12])) / tick
    return found


#: CPU s that threads other than the measuring one took during the measurements (a BLAS pool's spin-wait, numba's
#: threading layer, MuJoCo's pool would show here), summed over every measurement of :func:`_timed`.
OTHER_THREADS_CPU_S = [0.0]


def _timed(fn) -> tuple[float, float]:  # noqa: ANN001
    """(wall s, process CPU s: every thread of the process) of ``fn()``; the other threads' share is added to
    OTHER_THREADS_CPU_S."""
    before, me = _threads_cpu_s(), threading.get_native_id()
    w0, c0 = time.perf_counter(), time.process_time()
    fn()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    after = _threads_cpu_s()
    OTHER_THREADS_CPU_S[0] += sum(v - before.get(k, 0.0) for k, v in after.items() if k != me)
    return wall, cpu


class _InitialState:
    """An observer that keeps the plant's full physics state and warm start as the run starts."""

    def __init__(self, plant: Plant) -> None:
        self.plant = plant

    def on_start(self, run, trace) -> None:  # noqa: ANN001
        model, data = self.plant.model, self.plant.data
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self.state = np.empty(mujoco.mj_stateSize(model, spec))
        mujoco.mj_getState(model, data, self.state, spec)
        self.warmstart = data.qacc_warmstart.copy()
        self.ctrl = data.ctrl.copy()

    def on_chunk(self, trace, start: int, stop: int) -> None: ...  # noqa: ANN001

    def on_end(self, trace) -> None: ...  # noqa: ANN001


class Replay:
    """A closed-loop run's commands, to replay with ``mujoco.rollout`` from the run's initial state."""

    def __init__(self, name: str, seconds: float, friction: str = "coulomb") -> None:
        self.plant = Plant(friction=Friction(model=friction))
        start = _InitialState(self.plant)
        trace = simulate(self.plant, circle(), TimingLaw(2.0), create(name), seconds, observers=[start])
        ctrl = np.tile(start.ctrl, (trace.t_s.size, 1))
        ctrl[:, self.plant.motor_index] = trace.u_v
        ctrl[:, self.plant.disturbance_index] = trace.disturbance_v
        self.control = np.repeat(ctrl, self.plant.substeps, axis=0)[None]
        self.initial, self.warmstart, self.q_m = start.state[None], start.warmstart[None], trace.q_m
        self.data = mujoco.MjData(self.plant.model)

    def run(self) -> np.ndarray:
        """The rollout's states (1, steps, nstate)."""
        model, data = self.plant.model, self.data
        return rollout.rollout(model, data, self.initial, self.control, initial_warmstart=self.warmstart)[0]

    def check(self) -> float:
        """Largest |q| difference between the replay and the closed loop's true positions, m (0: the same physics)."""
        states = self.run()[0]
        qpos = states[self.plant.substeps - 1 :: self.plant.substeps, 1:][:, self.plant.qpos_index]
        return float(np.max(np.abs(qpos[:-1] - self.q_m[1:])))

    def timed(self) -> tuple[float, float]:
        return _timed(self.run)


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


def compile_costs() -> None:
    """Cold compiles (fresh cache) of all four built-in loops and of one DIARC run, and the load of all four."""
    builtin = tuple(name for name in CONTROLLERS if name != "example_pd")
    with tempfile.TemporaryDirectory() as cache:
        cold = _child(_FIRST_USE.format(names=builtin), cache)
        warm = _child(_FIRST_USE.format(names=builtin), cache)
    with tempfile.TemporaryDirectory() as cache:
        alone = _child(_FIRST_USE.format(names=("diarc",)), cache)
    rows = [
        ("cold compile, all four built-in loops (target 16 s CPU)", cold),
        ("cold compile, one DIARC run", alone),
        ("cache load, all four (target 0.3 s)", warm),
    ]
    print(f"numba, each in a fresh process (import {warm['import_s']:.2f} s CPU before it):")
    for label, result in rows:
        print(f"  {label:<58}{result['first_runs_cpu_s']:7.2f} s CPU {result['first_runs_wall_s']:7.2f} s wall")


def _cli_run(out: str, cache: str) -> tuple[float, float]:
    """(CPU s of the child: user + sys, wall s) of ``gantry-twin run`` (the default scenario) into ``out``."""
    env = dict(os.environ, PYTHONPATH=SRC + os.pathsep + os.environ.get("PYTHONPATH", ""), NUMBA_CACHE_DIR=cache)
    command = [sys.executable, "-m", "gantry_twin", "run", "--out", out]
    w0 = time.perf_counter()
    child = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - w0
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"{' '.join(command)} failed")
    return usage.ru_utime + usage.ru_stime, wall


def first_run_costs() -> None:
    """The README's first ``gantry-twin run`` from an empty cache, then a second run, in fresh processes."""
    with tempfile.TemporaryDirectory() as tmp:
        cache = os.path.join(tmp, "numba")
        (cold_cpu, cold_wall), (warm_cpu, warm_wall) = (_cli_run(os.path.join(tmp, f"run{i}"), cache) for i in (0, 1))
    print(
        f"gantry-twin run (default scenario), empty cache: {cold_cpu:.1f} s CPU {cold_wall:.1f} s wall; second run: "
        f"{warm_cpu:.1f} s CPU {warm_wall:.1f} s wall; first / second {cold_cpu / warm_cpu:.2f}x CPU (target 3.3x)"
    )


def pairs(count: int, seconds: float) -> None:
    """DIARC and pd against their rollouts, measured alternately ``count`` times: the median and the spread of the
    pairwise CPU ratios (how much one measurement can say on a shared machine)."""
    replays = {name: Replay(name, seconds) for name in ("diarc", "pd")}
    load_before = _load()
    ratios: dict[str, list[float]] = {"diarc": [], "pd": []}
    cpu: dict[str, list[float]] = {"diarc": [], "pd": [], "diarc rollout": [], "pd rollout": []}
    for _ in range(count):
        for name in ratios:
            own, floor = loop(name, seconds)[1], replays[name].timed()[1]
            ratios[name].append(own / floor)
            cpu[name].append(own)
            cpu[f"{name} rollout"].append(floor)
    for name, values in ratios.items():
        median = statistics.median(cpu[name]) / statistics.median(cpu[f"{name} rollout"])
        shown = ", ".join(f"{v:.2f}" for v in values)
        print(f"{name} / its rollout, {count} pairs of {seconds:g} s: medians {median:.3f}x CPU; pairs {shown}")
    print(
        f"threads other than the loop's: {OTHER_THREADS_CPU_S[0]:.3f} s of CPU; load average {load_before} before, "
        f"{_load()} after"
    )


def _load() -> str:
    """The load average over 1, 5 and 15 minutes."""
    return "/".join(f"{v:.1f}" for v in os.getloadavg())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=4.0, help="simulated seconds per loop measurement")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--skip-memory", action="store_true")
    parser.add_argument("--friction-only", action="store_true", help="only the Coulomb / LuGre comparison")
    parser.add_argument("--skip-compile", action="store_true", help="leave out the cold-compile measurements")
    parser.add_argument("--skip-first-run", action="store_true", help="leave out the first gantry-twin run")
    parser.add_argument("--only-compile", action="store_true", help="only the compile and first-run measurements")
    parser.add_argument("--pairs", type=int, metavar="N", help="only DIARC and pd against their rollouts, N pairs")
    args = parser.parse_args()
    if args.pairs:
        pairs(args.pairs, args.seconds)
        return
    ts = 2e-4
    n = int(round(args.seconds / ts))

    if args.friction_only:
        friction_costs(args.seconds, args.repeats, n)
        return
    if not args.skip_compile:
        compile_costs()
    if not args.skip_first_run:
        first_run_costs()
    if args.only_compile:
        return

    _example_plugin()
    load_before = _load()
    replays = {name: Replay(name, args.seconds) for name in CONTROLLERS}  # also loads (or compiles) every loop
    mismatch = max(replay.check() for replay in replays.values())
    at_rest = "mj_step at rest"
    results: dict[str, list[tuple[float, float]]] = {at_rest: []}
    for name in CONTROLLERS:
        results[name], results[f"{name} rollout"] = [], []
    for _ in range(args.repeats):
        results[at_rest].append(bare_steps(n))
        for name in CONTROLLERS:
            results[name].append(loop(name, args.seconds))
            results[f"{name} rollout"].append(replays[name].timed())
    ref_seconds = min(0.5, args.seconds)
    results["diarc (reference)"] = [loop("diarc", ref_seconds, "reference")]
    steps = {key: (int(round(ref_seconds / ts)) if "reference" in key else n) for key in results}
    best = {  # the median of the repeats: under load the best of them flatters whichever was least disturbed
        key: (
            statistics.median(w for w, _ in v) / steps[key] * 1e6,
            statistics.median(c for _, c in v) / steps[key] * 1e6,
        )
        for key, v in results.items()
    }

    print(
        f"\nloops of {args.seconds:g} s simulated ({n} steps), median of {args.repeats}; simulate() with recording to "
        f"memory and the derived errors, circle, default sensing. Floor: each loop's own commands replayed with "
        f"mujoco.rollout from its initial state (positions equal to the trace's within {mismatch:.1e} m)."
    )
    print(
        f"{'loop':<22}{'wall us/step':>13}{'x rollout':>10}{'CPU us/step':>13}{'x rollout':>10}"
        f"{'rollout wall':>14}{'rollout CPU':>13}{'x at rest':>11}"
    )
    rest_wall, rest_cpu = best[at_rest]
    print(f"{at_rest:<22}{rest_wall:13.2f}{'':>10}{rest_cpu:13.2f}")
    for key in [*CONTROLLERS, "diarc (reference)"]:
        wall, cpu = best[key]
        floor_wall, floor_cpu = best[f"{key.split()[0]} rollout"]
        label = key if "reference" in key else f"{key} (compiled)"
        print(
            f"{label:<22}{wall:13.2f}{wall / floor_wall:10.2f}{cpu:13.2f}{cpu / floor_cpu:10.2f}"
            f"{floor_wall:14.2f}{floor_cpu:13.2f}{floor_cpu / rest_cpu:11.2f}"
        )

    def ratio(name: str) -> str:
        (wall, cpu), (floor_wall, floor_cpu) = best[name], best[f"{name} rollout"]
        return f"{cpu / floor_cpu:.2f}x CPU, {wall / floor_wall:.2f}x wall"

    (pd_wall, pd_cpu), (ex_wall, ex_cpu) = best["pd"], best["example_pd"]
    print(
        f"\nDIARC / its rollout: {ratio('diarc')} (target 1.20x); pd / its rollout: {ratio('pd')} (target 1.10x); "
        f"example plug-in / built-in pd: {ex_cpu / pd_cpu:.2f}x CPU, {ex_wall / pd_wall:.2f}x wall"
    )
    print(
        f"threads other than the loop's took {OTHER_THREADS_CPU_S[0]:.3f} s of CPU over every measurement above; "
        f"load average {load_before} before, {_load()} after"
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
