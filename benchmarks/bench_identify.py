"""The many-seed study behind the identification acceptance (docs/logs.md).

    PYTHONPATH=src python benchmarks/bench_identify.py [--seeds 10] [--first 100]

For each seed a twin is drawn as the acceptance draws them (``excite.random_plant``: payload 0-10 kg, B and
Af +-30 %, the 0.5 um encoder of the default sensing), and two logs are made and identified separately:
the 20 s excitation (``excite.design``) under PD, and a 30 s log of the paper's ellipse under DIARC (paper
settings). Printed per seed and log: the largest relative error of M1, M2 and of B1, B2, Af1, Af2 (%), and
whether the truth lies inside the 95 % interval; at the end the worst over all seeds against the targets
(M 1 % / B, Af 3 % for the excitation; 2 % / 5 % for the ellipse).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from gantry_twin.controllers import create
from gantry_twin.loop.simulate import simulate
from gantry_twin.paths.contours import TimingLaw, paper_ellipse
from gantry_twin.sysid.identify import identify
from gantry_twin.sysid.logs import Log
from gantry_twin.sysid.trajectory import design, random_plant, run_on_twin

TARGETS = {"excitation 20 s": (1.0, 3.0), "ellipse 30 s": (2.0, 5.0)}


def as_log(trace) -> Log:
    n = trace.filled
    return Log("twin", trace.t_s[:n], trace.u_v[:n], trace.q_meas_m[:n], trace.q_d_m[:n], trace.sample_period_s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first", type=int, default=100)
    args = parser.parse_args()
    worst = {k: [0.0, 0.0] for k in TARGETS}
    outside = {k: 0 for k in TARGETS}
    path = design(20.0)
    for seed in range(args.first, args.first + args.seeds):
        plant = random_plant(np.random.default_rng(seed))
        truth = plant.true_parameters()
        started = time.perf_counter()
        traces = {
            "excitation 20 s": run_on_twin(path, plant),
            "ellipse 30 s": simulate(plant, paper_ellipse(), TimingLaw(3.0), create("diarc"), duration_s=30.0),
        }
        for name, trace in traces.items():
            result = identify([as_log(trace)])
            err = 100.0 * np.abs(result.theta[:6] - truth[:6]) / truth[:6]
            covered = (result.ci95[:6, 0] <= truth[:6]) & (truth[:6] <= result.ci95[:6, 1])
            outside[name] += int((~covered).sum())
            worst[name] = [max(worst[name][0], err[:2].max()), max(worst[name][1], err[2:].max())]
            print(
                f"seed {seed} {name:16s} M {err[:2].max():6.3f} %  B/Af {err[2:].max():6.3f} %  "
                f"truth outside ci95: {int((~covered).sum())}/6  (payload {truth[0] * 69 - 8.28:.2f} kg)",
                flush=True,
            )
        print(f"  ({time.perf_counter() - started:.1f} s)", flush=True)
    for name, (m_target, other_target) in TARGETS.items():
        m, other = worst[name]
        print(
            f"worst over {args.seeds} seeds, {name}: M {m:.3f} % (target {m_target} %), B/Af {other:.3f} % "
            f"(target {other_target} %); truth outside ci95 in {outside[name]} of {6 * args.seeds} parameters"
        )


if __name__ == "__main__":
    main()
