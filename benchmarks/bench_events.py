"""Cost of the end-stop and saturation scan (gantry_twin.loop.events) over the longest run allowed.

    PYTHONPATH=src python benchmarks/bench_events.py [--seconds 3600]

A synthetic trace of ``--seconds`` at 5 kHz (positions inside the travel,
commands inside the limits: the scan's usual case) is scanned three ways:
:func:`gantry_twin.loop.events.travel_summary` (what ``write_run`` does, block by
block), chunk by chunk as a simulate observer (0.1 s chunks), and in one
piece. Prints the wall time and the growth of the peak RSS of each; run it in a
fresh process per way (``--way``) for the RSS to mean anything.
"""

from __future__ import annotations

import argparse
import resource
import time
import types

import numpy as np

from gantry_twin import Plant
from gantry_twin.loop.events import TravelWatch, travel_summary

SAMPLE_PERIOD_S = 2e-4
CHUNK = 500  # simulate's default chunk, 0.1 s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3600.0)
    parser.add_argument("--way", choices=("summary", "chunks", "whole"), default="summary")
    args = parser.parse_args()
    n = int(round(args.seconds / SAMPLE_PERIOD_S))
    rng = np.random.default_rng(0)
    t = np.arange(n) * SAMPLE_PERIOD_S
    q = rng.uniform(-0.2, 0.2, (n, 2))
    u = rng.uniform(-9.0, 9.0, (n, 2))
    plant = Plant()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    start = time.perf_counter()
    if args.way == "summary":
        travel_summary(plant, types.SimpleNamespace(t_s=t, q_m=q, u_v=u, filled=n))
    else:
        watch = TravelWatch(plant)
        step = CHUNK if args.way == "chunks" else n
        for a in range(0, n, step):
            watch.scan(t[a : a + step], q[a : a + step], u[a : a + step])
    wall = time.perf_counter() - start
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    print(f"{args.way}: {n} samples ({args.seconds:g} s) in {wall:.2f} s, peak RSS +{grown_mb:.0f} MB")


if __name__ == "__main__":
    main()
