"""Trials per minute of ``gantry-twin tune`` with 1 and with 2 workers, side by side in one run (docs/tune.md).

    PYTHONPATH=src python benchmarks/bench_tune.py [--trials 32] [--duration 4.3] [--workers 1 2]

One tune of ``--trials`` trials (PD on the paper's circle, two plants: each
trial two runs of ``--duration`` simulated seconds; 4.3 s by default, the
shorter run of the shipped specs in tunes/, so that a trial weighs what a
user's does) by
:func:`gantry_twin.tune.run_tune` on a LocalCluster of each ``--workers``
count, into a temporary directory. Printed per count: startup (cluster,
warm-up, the baseline's runs) and trials (first trial asked to last told),
trials per minute, the process CPU of the driver; then the ratio of the last
count's throughput to the first's (target: 2 workers >= 1.7 x 1 worker).
Measure on a quiet machine: the load average before each tune is printed.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from gantry_twin.tune import parse_tune, plan_tune, run_tune

RATIO_MIN = 1.7

SPEC = """\
set: {{controller.name: pd, controller.options: {{kp_v_m: [10000, 10000], kd_v_s_m: [100, 100]}},
      duration_s: {duration}, plant.model: paper}}
scenarios: [{{scenario: no_load_circle}}]
ensemble:
  - {{name: light, set: {{plant.model: paper}}}}
  - {{name: heavy, set: {{plant.model: paper, payload.mass_kg: 5}}}}
design:
  - {{field: controller.options.kp_v_m.0, low: 1000, high: 100000, log: true, name: kp_x}}
  - {{field: controller.options.kd_v_s_m.0, low: 10, high: 1000, log: true, name: kd_x}}
goals:
  - {{metric: contour_rms_um, limit: 1, kind: soft}}
optimiser: {{trials: {trials}, startup_trials: 4}}
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=32)  # 16 read 1.66-2.03x in one hour
    parser.add_argument(
        "--duration", type=float, default=4.3, help="simulated seconds per run (the shipped specs' shorter run)"
    )
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    print(f"{args.trials} trials of 2 runs of {args.duration:g} s, PD; {os.cpu_count()} cores")
    rates = []
    with tempfile.TemporaryDirectory(prefix="bench-tune-") as tmp:
        spec_path = Path(tmp) / "bench.yaml"
        spec_path.write_text(SPEC.format(duration=args.duration, trials=args.trials))
        plan = plan_tune(parse_tune(spec_path.read_text(), str(spec_path)), str(spec_path))
        for workers in args.workers:
            load = os.getloadavg()[0]
            started, cpu = time.perf_counter(), time.process_time()
            outcome = run_tune(plan, Path(tmp) / f"w{workers}", args.trials, workers=workers)
            wall = time.perf_counter() - started
            rate = 60.0 * outcome.ran / outcome.trials_s
            rates.append(rate)
            print(
                f"workers {workers}: load {load:.1f}; startup {wall - outcome.trials_s:.1f} s, "
                f"trials {outcome.trials_s:.1f} s, {rate:.1f} trials/min; driver CPU {time.process_time() - cpu:.1f} s"
            )
    ratio = rates[-1] / rates[0]
    verdict = "meets" if ratio >= RATIO_MIN else "below"
    print(f"ratio {args.workers[-1]} / {args.workers[0]} workers: {ratio:.2f}x ({verdict} the {RATIO_MIN}x target)")


if __name__ == "__main__":
    main()
