"""Where a cold compile of one controller's loop goes, kernel by kernel (docs/performance.md, "Compile").

    PYTHONPATH=src python benchmarks/bench_compile_parts.py [--controller diarc] [--rounds 2]

Each round runs, in a fresh process with an empty ``NUMBA_CACHE_DIR``,
``simulate()`` of 0.01 s with the controller (the compile of its loop and of
every kernel the loop calls), and prints per kernel:

* ``own``: CPU s of its compile less the compiles of the kernels it calls
  (numba's ``numba:compile`` events, nested);
* ``llvm``: of that, LLVM's work on its library: the function passes on
  its new IR, the module passes after the kernels it calls are linked in,
  and the machine code (numba's ``CPUCodeLibrary`` stages);
* ``lower``: of that, numba's lowering of its typed IR to LLVM IR;
* ``with callees``: its compile including the kernels it calls.

The rest of ``own`` is numba's front end (bytecode analysis, type inference,
inlining) and its CPython wrapper. CPU is ``time.process_time()`` (all
threads) in the child, after its imports.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

_CHILD = """
import collections, json, sys, time
from numba.core import codegen, event, lowering

stack, own, inclusive = [], collections.Counter(), collections.Counter()
llvm, lower = collections.Counter(), collections.Counter()


class Compiles(event.Listener):
    def on_start(self, ev):
        stack.append([ev.data["dispatcher"].py_func.__qualname__[:48], time.process_time(), 0.0])

    def on_end(self, ev):
        name, t0, callees = stack.pop()
        spent = time.process_time() - t0
        inclusive[name] += spent
        own[name] += spent - callees
        if stack:
            stack[-1][2] += spent


def timed(cls, method, counter):
    original = getattr(cls, method)

    def wrapper(self, *args, **kwargs):
        t0 = time.process_time()
        try:
            return original(self, *args, **kwargs)
        finally:
            if stack:
                counter[stack[-1][0]] += time.process_time() - t0

    setattr(cls, method, wrapper)


event.register("numba:compile", Compiles())
for method in ("_optimize_functions", "_optimize_final_module"):
    timed(codegen.CPUCodeLibrary, method, llvm)
timed(codegen.JITCodeLibrary, "_finalize_specific", llvm)
timed(lowering.BaseLower, "lower", lower)

from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import create

t0 = time.process_time()
simulate(Plant(), circle(), TimingLaw(2.0), create(sys.argv[1]), duration_s=0.01)
total = time.process_time() - t0
rows = [[name, own[name], llvm[name], lower[name], inclusive[name]] for name in own]
print(json.dumps({"total": total, "rows": rows}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controller", default="diarc")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--top", type=int, default=16, help="kernels listed, the costliest first")
    args = parser.parse_args()
    env = dict(os.environ, PYTHONPATH=os.path.join(ROOT, "src") + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for r in range(args.rounds):
        with tempfile.TemporaryDirectory() as cache:
            out = subprocess.run(
                [sys.executable, "-c", _CHILD, args.controller],
                env=dict(env, NUMBA_CACHE_DIR=cache),
                capture_output=True,
                text=True,
                check=True,
            )
        result = json.loads(out.stdout.strip().splitlines()[-1])
        rows = sorted(result["rows"], key=lambda row: -row[1])
        load = os.getloadavg()[0]
        own, llvm, lower = (sum(row[i] for row in rows) for i in (1, 2, 3))
        print(
            f"round {r}: one {args.controller} run from an empty cache, {result['total']:.2f} s CPU "
            f"(kernels {own:.2f}: LLVM {llvm:.2f}, lowering {lower:.2f}, the rest of numba {own - llvm - lower:.2f}); "
            f"load average {load:.1f}"
        )
        print(f"  {'kernel':<50}{'own':>7}{'llvm':>7}{'lower':>7}{'with callees':>14}")
        for name, mine, ll, lo, incl in rows[: args.top]:
            print(f"  {name:<50}{mine:7.2f}{ll:7.2f}{lo:7.2f}{incl:14.2f}")


if __name__ == "__main__":
    main()
