"""Integrator and physics sub-steps of a LuGre plant: accuracy against a 2 us reference, and cost (docs/friction.md).

    PYTHONPATH=src python benchmarks/friction_integration.py [--seconds 2] [--scenarios no_load_circle ...]
        [--candidates euler:4 rk4:8 ...] [--set sensing.quantize=false ...]

Runs shipped scenarios with ``plant.friction.model: lugre`` (default LuGre
parameters), the controller at 0.2 ms as always, for each integrator and
number of physics steps per sample, and compares eps_c with the same run
whose physics steps at 2 us (RK4, 100 sub-steps per sample). Prints, per
candidate, the largest |eps_c - eps_c_ref| over the scenarios (um), whether
MuJoCo warned (a diverged and reset state), and the loop's cost per 0.2 ms
sample (compiled backend, best of 3). The choice is written in docs/friction.md.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from gantry_twin.run import execute
from gantry_twin.scenario import build, load_scenario
from gantry_twin.scenario.files import shipped

REFERENCE = ("rk4", 100)
CANDIDATES = [(i, n) for i in ("euler", "implicitfast", "rk4") for n in (1, 2, 4, 8)]
PAPER_SCENARIOS = ("no_load_circle", "no_load_ellipse", "load_5kg_circle", "load_5kg_ellipse")


def run(
    name: str, integrator: str, substeps: int, seconds: float, extra: tuple[str, ...] = ()
) -> tuple[np.ndarray, bool, float]:
    """eps_c (m), any MuJoCo warning, wall seconds per sample."""
    overrides = [
        *extra,
        "plant.friction.model=lugre",
        f"plant.friction.integrator={integrator}",
        f"plant.friction.substeps={substeps}",
        f"duration_s={seconds}",
        f"window_s=[0.0, {seconds}]",
        f"estimates_window_s=[0.0, {seconds}]",
    ]
    best = np.inf
    for _ in range(3):
        built = build(load_scenario(shipped(name), overrides))
        t0 = time.perf_counter()
        trace = execute(built)
        best = min(best, (time.perf_counter() - t0) / trace.t_s.size)
    warned = any(w.number > 0 for w in built.plant.data.warning)
    return np.asarray(trace.eps_c_m).copy(), warned, best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--scenarios", nargs="*", default=list(PAPER_SCENARIOS))
    parser.add_argument("--candidates", nargs="*", default=[f"{i}:{n}" for i, n in CANDIDATES], help="integrator:n")
    parser.add_argument("--set", nargs="*", default=[], help="scenario overrides, e.g. sensing.quantize=false")
    args = parser.parse_args()
    extra = tuple(args.set)
    run(args.scenarios[0], "euler", 1, 0.01)  # compile the loop first
    refs = {name: run(name, *REFERENCE, args.seconds, extra)[0] for name in args.scenarios}
    print(f"{args.seconds:g} s of {', '.join(args.scenarios)}; reference: {REFERENCE[0]} x{REFERENCE[1]} (2 us)")
    print(f"overrides: {' '.join(extra) or 'none'}")
    print(f"{'integrator':<14}{'substeps':>9}{'max |d eps_c| um':>18}{'warning':>9}{'us/sample':>11}")
    for candidate in args.candidates:
        integrator, substeps = candidate.split(":")[0], int(candidate.split(":")[1])
        worst, warned, cost = 0.0, False, 0.0
        for name in args.scenarios:
            eps, w, c = run(name, integrator, substeps, args.seconds, extra)
            diff = np.abs(eps - refs[name])
            worst = max(worst, float(np.nanmax(diff)) if np.isfinite(diff).any() else np.inf)
            warned |= w
            cost = max(cost, c)
        print(
            f"{integrator:<14}{substeps:>9}{worst * 1e6:>18.3f}{'yes' if warned else 'no':>9}{cost * 1e6:>11.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
