"""The cold start, side by side in one command (docs/performance.md, "Cold start").

    PYTHONPATH=src python benchmarks/bench_cold_start.py [--rounds 1]

Each round, in fresh processes with their own empty ``NUMBA_CACHE_DIR``:

* the four built-in loops (pd, drc, darc, diarc: a 0.01 s run each, after the imports) compiled from the empty
  cache, then loaded from it: CPU s of the process (``time.process_time``, every thread);
* the README's ``gantry-twin run`` (the default scenario, 30 s of DIARC) from an empty cache, then a second run
  from the cache it filled: CPU s of each child (user + sys, every thread, ``os.wait4``);

printed side by side with the targets (the four loops in at most 16 s of CPU; the first run at most 3.3x the second)
and the load average before and after each measurement: the machine may be shared, so read the ratio of two
measurements taken side by side, and say which were taken under load.
"""

from __future__ import annotations

import argparse
import os
import tempfile

from bench_loop import _FIRST_USE, _child, _cli_run

BUILT_IN = ("pd", "drc", "darc", "diarc")
#: The targets (docs/performance.md, "Cold start"): numba's own floor, measured.
COMPILE_TARGET_S = 16.0
FIRST_RUN_TARGET = 3.3


def _load() -> str:
    return "/".join(f"{v:.1f}" for v in os.getloadavg())


def one_round() -> dict[str, float | str]:
    """One round's numbers (CPU s) and the load averages (1, 5, 15 min) around each."""
    row: dict[str, float | str] = {}
    with tempfile.TemporaryDirectory() as cache:
        row["load_compile"] = _load()
        cold = _child(_FIRST_USE.format(names=BUILT_IN), cache)
        warm = _child(_FIRST_USE.format(names=BUILT_IN), cache)
    row |= {"compile_s": cold["first_runs_cpu_s"], "load_s": warm["first_runs_cpu_s"], "import_s": warm["import_s"]}
    with tempfile.TemporaryDirectory() as tmp:
        cache = os.path.join(tmp, "numba")
        row["load_run"] = _load()
        (first, first_wall), (second, second_wall) = (_cli_run(os.path.join(tmp, f"run{i}"), cache) for i in (0, 1))
    row |= {"first_s": first, "second_s": second, "first_wall_s": first_wall, "second_wall_s": second_wall}
    row["load_end"] = _load()
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=1)
    args = parser.parse_args()
    print(
        f"{'round':>5} {'4 loops, cold':>14} {'(<= 16 s)':>9} {'cache load':>11} {'1st run':>8} {'2nd run':>8} "
        f"{'1st/2nd':>8} {'(<= 3.3x)':>9}   load avg 1/5/15 min: compile | runs | end"
    )
    for i in range(args.rounds):
        r = one_round()
        ratio = float(r["first_s"]) / float(r["second_s"])
        print(
            f"{i:5d} {r['compile_s']:12.1f} s {'met' if r['compile_s'] <= COMPILE_TARGET_S else 'NOT met':>9} "
            f"{r['load_s']:9.2f} s {r['first_s']:6.1f} s {r['second_s']:6.1f} s {ratio:7.2f}x "
            f"{'met' if ratio <= FIRST_RUN_TARGET else 'NOT met':>9}   {r['load_compile']} | {r['load_run']} | "
            f"{r['load_end']}",
            flush=True,
        )
    print(
        "CPU seconds: the compile and the cache load after the imports "
        f"({r['import_s']:.2f} s), each run's whole child process (user + sys, imports included); walls "
        f"{r['first_wall_s']:.1f} s and {r['second_wall_s']:.1f} s for the last round's runs"
    )


if __name__ == "__main__":
    main()
