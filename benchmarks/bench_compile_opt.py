"""numba's LLVM settings against the cold compile and the loop's cost per step (docs/performance.md, "Compile").

    PYTHONPATH=src python benchmarks/bench_compile_opt.py [--configs 3:1:0 1:1:0] [--rounds 2]

Each configuration is ``opt:loop_vectorize:slp_vectorize`` (``NUMBA_OPT``,
``NUMBA_LOOP_VECTORIZE``, ``NUMBA_SLP_VECTORIZE``; numba's defaults are
``3:1:0``). ``default`` runs with none of them set (the package's own choice).
For each round and configuration (the order rotated every round, so that
every configuration meets the machine's load in turn), two fresh processes
with an empty ``NUMBA_CACHE_DIR``:

* one DIARC run's compile (``simulate`` of 0.01 s);
* the loops of all four built-in controllers (pd, drc, darc, diarc), then,
  in the same process, the loop's cost: ``simulate()`` of pd and DIARC on the
  circle and the ``mujoco.rollout`` of each run's own commands, interleaved,
  best of ``--repeats``, us per step in process CPU time (all threads) and
  wall, and their ratio (benchmarks/bench_loop.py measures the same way).

CPU is ``time.process_time()`` in the child after its imports (all threads).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SRC = os.path.join(ROOT, "src")
BENCH = os.path.join(ROOT, "benchmarks")

_CHILD = """
import json, sys, time
sys.path.insert(0, {bench!r})
w0, c0 = time.perf_counter(), time.process_time()
import numba
from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import create
w1, c1 = time.perf_counter(), time.process_time()
for name in {names!r}:
    simulate(Plant(), circle(), TimingLaw(2.0), create(name), duration_s=0.01)
w2, c2 = time.perf_counter(), time.process_time()
out = {{"import_s": c1 - c0, "compile_cpu_s": c2 - c1, "compile_wall_s": w2 - w1,
        "opt": int(numba.config.OPT), "loop_vectorize": int(numba.config.LOOP_VECTORIZE),
        "slp_vectorize": int(numba.config.SLP_VECTORIZE)}}
if {seconds!r} > 0:
    import bench_loop
    n = int(round({seconds!r} / 2e-4))
    replays = {{name: bench_loop.Replay(name, {seconds!r}) for name in ("pd", "diarc")}}
    times = {{}}
    for _ in range({repeats!r}):
        for name, replay in replays.items():
            times.setdefault(name, []).append(bench_loop.loop(name, {seconds!r}))
            times.setdefault(name + " rollout", []).append(replay.timed())
    for key, values in times.items():
        out[key] = (min(w for w, _ in values) / n * 1e6, min(c for _, c in values) / n * 1e6)
print(json.dumps(out))
"""


def _env(config: str, cache: str) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=SRC + os.pathsep + os.environ.get("PYTHONPATH", ""), NUMBA_CACHE_DIR=cache)
    for key in ("NUMBA_OPT", "NUMBA_LOOP_VECTORIZE", "NUMBA_SLP_VECTORIZE"):
        env.pop(key, None)
    if config != "default":
        opt, loop, slp = config.split(":")
        env.update(NUMBA_OPT=opt, NUMBA_LOOP_VECTORIZE=loop, NUMBA_SLP_VECTORIZE=slp)
    return env


def _child(config: str, names: tuple[str, ...], seconds: float, repeats: int) -> dict:
    """The child's measurements, run with an empty cache and the configuration's settings."""
    code = _CHILD.format(bench=BENCH, names=names, seconds=seconds, repeats=repeats)
    with tempfile.TemporaryDirectory() as cache:
        with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
            proc = subprocess.Popen([sys.executable, "-c", code], env=_env(config, cache), stdout=out, stderr=err)
            _, status, _ = os.wait4(proc.pid, 0)
            out.seek(0)
            err.seek(0)
            if os.waitstatus_to_exitcode(status) != 0:
                raise RuntimeError(f"{config}: child failed\n{err.read().decode()[-2000:]}")
            result = json.loads(out.read().decode().strip().splitlines()[-1])
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", nargs="+", default=["3:1:0", "2:1:0", "1:1:0", "0:1:0", "3:0:0", "3:1:1"])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per loop measurement")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    builtin = ("pd", "drc", "darc", "diarc")
    print(f"load average at start: {os.getloadavg()}", flush=True)
    header = (
        f"{'round':>5} {'config':>8} {'diarc CPU s':>12} {'four CPU s':>11} {'four wall':>10}"
        f"{'diarc us CPU':>13}{'x roll':>7}{'us wall':>8}{'x roll':>7}"
        f"{'pd us CPU':>10}{'x roll':>7}{'us wall':>8}{'x roll':>7}  load"
    )
    print(header, flush=True)
    for r in range(args.rounds):
        shift = r % len(args.configs)
        for config in args.configs[shift:] + args.configs[:shift]:
            alone = _child(config, ("diarc",), 0.0, 0)
            four = _child(config, builtin, args.seconds, args.repeats)
            cells = []
            for name in ("diarc", "pd"):
                (wall, cpu), (rwall, rcpu) = four[name], four[f"{name} rollout"]
                cells.append(f"{cpu:13.2f}{cpu / rcpu:7.2f}{wall:8.2f}{wall / rwall:7.2f}")
            print(
                f"{r:>5} {config:>8} {alone['compile_cpu_s']:12.2f} {four['compile_cpu_s']:11.2f} "
                f"{four['compile_wall_s']:10.2f}{cells[0]}{cells[1]}  "
                f"{os.getloadavg()[0]:.1f} (opt {four['opt']} lv {four['loop_vectorize']} slp {four['slp_vectorize']})",
                flush=True,
            )


if __name__ == "__main__":
    main()
