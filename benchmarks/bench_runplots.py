"""Time to draw a run's figures (plots/*.png, gantry_twin.outputs.plots) beside the time of the run itself.

    PYTHONPATH=src python benchmarks/bench_runplots.py [--scenario no_load_circle] [--duration 30] [--repeat 3]

Runs the scenario once as ``gantry-twin run --no-plots`` writes it (into a
temporary directory), then draws its figures from the written trace.parquet
``--repeat`` times, as ``gantry-twin run`` does at the end of a run. The first
drawing includes importing matplotlib (what a run pays); the later ones do not.
Wall and CPU time are printed: on a shared machine the CPU time is the steadier figure.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="no_load_circle")
    parser.add_argument("--duration", type=float, default=30.0, help="simulated seconds")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    from gantry_twin.run import PLOTS_DIR, RunWriter
    from gantry_twin.scenario import build, load_scenario, shipped

    path = shipped(args.scenario)
    built = build(load_scenario(path, [f"duration_s={args.duration:g}"]), str(path))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        with RunWriter(out, built) as writer:
            writer.run()  # compiles the loop first if needed: run it once before timing
        started = time.perf_counter()
        with RunWriter(out, built) as writer:
            outcome = writer.run()
        run_s = time.perf_counter() - started
        summary = json.loads((out / "summary.json").read_text())
        from gantry_twin.outputs.plots import write_plots

        draws, cpu = [], []
        for _ in range(args.repeat):
            started, started_cpu = time.perf_counter(), time.process_time()
            names = write_plots(out, out / PLOTS_DIR, summary)
            draws.append(time.perf_counter() - started)
            cpu.append(time.process_time() - started_cpu)
        size_mb = (out / "trace.parquet").stat().st_size / 1e6
    print(
        f"{args.scenario}, {args.duration:g} s ({outcome.summary.steps} steps, trace {size_mb:.0f} MB): "
        f"run and write {run_s:.2f} s; draw {len(names)} figures {draws[0]:.2f} s "
        f"(matplotlib import included), then " + ", ".join(f"{d:.2f}" for d in draws[1:]) + " s wall; "
        "CPU " + ", ".join(f"{c:.2f}" for c in cpu) + " s"
    )


if __name__ == "__main__":
    main()
