"""The reversal-spike figure alone: eps_c +-50 ms around an X reversal of circle Set 1, C1-C3, rig twin against
the ideal twin (the figure `gantry-twin report` writes as rig_reversal_spike.png, without the report's matrix).

    PYTHONPATH=src python tools/reversal_spike.py OUT.png [--rig FILE] [--set FIELD=VALUE ...] [--plot-format ...]

Six short runs (each controller up to 50 ms past the first X reversal after its metric window's start, about
4 s simulated; `gantry_twin.reports.rig.spike_series`). The rig twin is the scenarios' plant (the rig plant,
models/rig.xml) with FILE's ``overrides`` (a calibration's fit.json, as `report --rig FILE`) and then the --set
ones, in that order; the ideal twin is `plant.model=paper`. Prints each run's largest |eps_c| in the +-50 ms and
when it comes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from gantry_twin.outputs.plots import DPI
from gantry_twin.reports.rig import LABELS, load_rig, spike_figure, spike_series
from gantry_twin.scenario import ScenarioError


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the figure's file (its suffix, .png .svg or .pdf, is its format)")
    parser.add_argument("--rig", type=Path, help="a JSON file with 'overrides' (a calibration's fit.json)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="FIELD=VALUE")
    args = parser.parse_args()
    try:
        rig = [*(load_rig(args.rig) if args.rig else []), *args.sets]
    except ScenarioError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    series = spike_series((), rig)
    for label in LABELS:
        for name in ("rig", "ideal"):
            t_ms, eps_um = series[(label, name)]
            at = int(np.argmax(np.abs(eps_um)))
            print(f"{label} {name} twin: max |eps_c| {abs(eps_um[at]):.2f} um at {t_ms[at]:+.1f} ms")
    fig = spike_figure(series)
    fig.savefig(args.out, dpi=DPI)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
