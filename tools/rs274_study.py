"""Every program of a LinuxCNC checkout through LinuxCNC's interpreter and the twin's reader: do they agree?

    python tools/rs274_study.py CHECKOUT [--list] [--timeout 60]

CHECKOUT is a LinuxCNC source tree (git clone https://github.com/LinuxCNC/linuxcnc); its programs are
read where they are (GPL-2: nothing is copied). Each ``*.ngc`` / ``*.nc`` under ``nc_files/`` and
``tests/trajectory-planner/circular-arcs/nc_files/`` runs through ``rs274 -g`` (in its own directory)
and through the reader with ``--drop-unsupported``'s option, and lands in one class:

- ``rs274 stops``: rs274 did not run it to its end (its message; such a program is not judged);
- ``not XY``: rs274's path has arcs in another plane (G18 / G19), probing or spindle-synchronised motion;
- ``beyond travel``: rs274's path leaves the twin's travel (+-255 mm per axis from the origin);
- ``agree``: same ends, arc centres and turns within 1 um (3 um inch), :mod:`gantry_twin.gcode.oracle`;
- ``differ``: the first disagreement;
- ``twin refuses``: the reader's one-line error.

Prints the counts (and with ``--list`` one line per program); exits 1 when a program that rs274 runs,
in XY and within the travel, the reader refuses or reads differently. docs/gcode.md gives the counts
measured.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from gantry_twin.gcode import GcodeError, read_program
from gantry_twin.gcode.oracle import compare, rs274_available, rs274_path, run_rs274, twin_path
from gantry_twin.gcode.program import TRAVEL_HALF_M

DIRECTORIES = ("nc_files", "tests/trajectory-planner/circular-arcs/nc_files")
SUFFIXES = (".ngc", ".nc")


def programs(checkout: Path) -> list[Path]:
    found = []
    for directory in DIRECTORIES:
        root = checkout / directory
        found += sorted(p for p in root.rglob("*") if p.suffix.lower() in SUFFIXES and p.is_file())
    return found


def judge(path: Path, timeout_s: float) -> tuple[str, str]:
    """(class, detail) of one program, as the module's docstring says."""
    code, output = run_rs274(path, timeout_s=timeout_s)
    oracle = rs274_path(code, output)
    if not oracle.ok:
        return "rs274 stops", oracle.message[:100]
    if not oracle.xy_plane or oracle.foreign:
        return "not XY", oracle.foreign or "arcs in another plane"
    half_mm = TRAVEL_HALF_M[0] * 1e3
    if max(abs(v) for v in oracle.extent_mm) > half_mm + 1e-6:
        return "beyond travel", "extent " + " ".join(f"{v:.1f}" for v in oracle.extent_mm) + " mm"
    try:
        twin = read_program(path, drop_unsupported=True, merge_lines=False)
    except GcodeError as error:
        return "twin refuses", str(error).replace(str(path), path.name)
    result = compare(oracle.points, twin_path(twin))
    if result.agreed:
        return "agree", f"{result.matched} points, worst {result.worst_mm * 1e3:.2f} um"
    return "differ", result.disagreement


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkout", type=Path, help="a LinuxCNC source tree")
    parser.add_argument("--list", action="store_true", help="one line per program")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds rs274 may take per program")
    args = parser.parse_args(argv)
    if rs274_available() is None:
        print("rs274_study: rs274 is not installed (Debian: apt install linuxcnc-uspace)", file=sys.stderr)
        return 2
    found = programs(args.checkout)
    if not found:
        print(f"rs274_study: no programs under {args.checkout}/{{{','.join(DIRECTORIES)}}}", file=sys.stderr)
        return 2
    counts: Counter[str] = Counter()
    details: Counter[str] = Counter()
    for path in found:
        kind, detail = judge(path.resolve(), args.timeout)
        counts[kind] += 1
        if kind in ("twin refuses", "differ", "not XY"):
            details[f"{kind}: {detail.split(': ', 1)[-1] if kind == 'twin refuses' else detail}"[:110]] += 1
        if args.list:
            print(f"{kind:14} {path.relative_to(args.checkout)}: {detail}")
    ordered = sorted(counts.items(), key=lambda item: (-item[1], item[0]))
    print(f"{len(found)} programs: " + ", ".join(f"{kind} {n}" for kind, n in ordered))
    for detail, n in details.most_common():
        print(f"  {n:3d} x {detail}")
    return 1 if counts["differ"] else 0


if __name__ == "__main__":
    sys.exit(main())
