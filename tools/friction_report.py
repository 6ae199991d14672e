"""The paper's matrix with the rig's friction beside the Coulomb twin, and the health monitor (docs/friction.md).

    PYTHONPATH=src python tools/friction_report.py FIT_JSON [--out runs/friction-report] [--jobs 2] [--monitor-s 60]

FIT_JSON: the ``fit.json`` of tools/calibrate_friction.py (its ``overrides``
make the rig plant). The table, the acceptance checks and the reversal-spike
figure are ``gantry-twin report --rig FIT_JSON``'s (gantry_twin.reports.rig);
this script writes them alone into ``friction.md`` (without the paper report)
and adds the health monitor on the four no-load / 5 kg paper scenarios over
``--monitor-s`` seconds with the rig plant.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from gantry_twin.reports import rig as rig_report
from gantry_twin.reports.paper import paper_matrix, run_matrix


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fit", type=Path)
    parser.add_argument("--out", type=Path, default=Path("runs/friction-report"))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--monitor-s", type=float, default=60.0)
    args = parser.parse_args()
    rig = rig_report.load_rig(args.fit)
    cases = paper_matrix()
    results = run_matrix([*cases, *rig_report.rig_cases(cases, rig)], jobs=args.jobs)
    lines = ["# The rig's friction vs the Coulomb twin (tools/friction_report.py)", ""]
    lines += rig_report.section(results[: len(cases)], results[len(cases) :], rig, args.out)
    lines += [f"## Health monitor, rig friction, {args.monitor_s:g} s, DIARC", ""]
    lines += rig_report.monitor_alarms(rig, args.monitor_s)
    (args.out / "friction.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
