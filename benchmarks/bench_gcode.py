"""Cost of reading and planning a long part program (gantry_twin.gcode): a 3D-printer-like polyline.

    PYTHONPATH=src python benchmarks/bench_gcode.py [--blocks 100000] [--run]

The program is ``--blocks`` G1 moves of 0.5 to 2 mm with turns of up to
40 deg (a random walk kept inside the travel), F6000, G64 P0.02. Prints the
time per block of reading and of planning, the time to sample the whole
reference at 0.2 ms and the peak RSS growth; with ``--run`` also the
closed-loop run time of the same program (DIARC, compiled loop, held in
pieces so memory stays bounded).
"""

from __future__ import annotations

import argparse
import math
import resource
import time

import numpy as np

from gantry_twin.gcode import parse_program
from gantry_twin.gcode.planner import plan_program

SAMPLE_PERIOD_S = 2e-4


def polyline(blocks: int, seed: int = 0) -> str:
    """A random-walk polyline of ``blocks`` short G1 moves inside +-200 mm."""
    rng = np.random.default_rng(seed)
    lines = ["G21 G90 G64 P0.02", "G0 X0 Y0", "F6000"]
    x = y = 0.0
    heading = 0.0
    for _ in range(blocks):
        heading += rng.uniform(-0.7, 0.7)
        step = rng.uniform(0.5, 2.0)
        nx, ny = x + step * math.cos(heading), y + step * math.sin(heading)
        if abs(nx) > 200 or abs(ny) > 200:
            heading += math.pi
            nx, ny = x + step * math.cos(heading), y + step * math.sin(heading)
        x, y = nx, ny
        lines.append(f"G1 X{x:.4f} Y{y:.4f}")
    lines.append("M30")
    return "\n".join(lines) + "\n"


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blocks", type=int, default=100_000)
    parser.add_argument("--run", action="store_true", help="also run the program in the closed loop")
    args = parser.parse_args()
    text = polyline(args.blocks)
    base = rss_mb()
    start = time.perf_counter()
    program = parse_program(text, name="polyline.ngc")
    read_s = time.perf_counter() - start
    after_read = rss_mb()
    start = time.perf_counter()
    plan = plan_program(program)
    plan_s = time.perf_counter() - start
    after_plan = rss_mb()
    start = time.perf_counter()
    n = int(round(plan.duration_s / SAMPLE_PERIOD_S))
    for first in range(0, n, 50_000):  # in pieces, as the loop's hold_s does
        plan.reference(np.arange(first, min(n, first + 50_000)) * SAMPLE_PERIOD_S)
    sample_s = time.perf_counter() - start
    blocks = len(program.moves)
    print(f"program: {blocks} moves, {len(text) / 1e6:.1f} MB of text, planned cycle time {plan.duration_s:.1f} s")
    print(f"read:   {read_s:.2f} s ({read_s / blocks * 1e6:.1f} us/block), peak RSS +{after_read - base:.0f} MB")
    print(f"plan:   {plan_s:.2f} s ({plan_s / blocks * 1e6:.1f} us/block), peak RSS +{after_plan - after_read:.0f} MB")
    print(f"sample: {sample_s:.2f} s for {n} samples at 0.2 ms ({sample_s / n * 1e6:.2f} us/sample)")
    print(f"peak RSS {rss_mb():.0f} MB")
    if args.run:
        from gantry_twin.controllers import create
        from gantry_twin.loop.simulate import simulate
        from gantry_twin.paths.contours import TimingLaw
        from gantry_twin.plant.model import Plant

        start = time.perf_counter()
        simulate(Plant(), plan, TimingLaw(1.0), create("diarc"), plan.duration_s, hold_s=10.0)
        run_s = time.perf_counter() - start
        print(f"run:    {run_s:.1f} s for {plan.duration_s:.1f} s simulated (DIARC), peak RSS {rss_mb():.0f} MB")


if __name__ == "__main__":
    main()
