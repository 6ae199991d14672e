"""Every program of a LinuxCNC checkout through LinuxCNC's interpreter and the twin's reader: do they agree?

    python tools/rs274_study.py CHECKOUT [--list] [--timeout 60] [--tool-table FILE]

CHECKOUT is a LinuxCNC source tree (git clone https://github.com/LinuxCNC/linuxcnc); its programs are
read where they are (GPL-2: nothing is copied). Each ``*.ngc`` / ``*.nc`` under ``nc_files/`` and
``tests/trajectory-planner/circular-arcs/nc_files/`` runs through ``rs274 -g`` and through the reader
with ``--drop-unsupported``'s option (both find a called subroutine file in the program's directory),
and lands in one class:

- ``rs274 stops``: rs274 did not run it to its end (its message; such a program is not judged);
- ``not XY``: rs274's path has arcs in another plane (G18 / G19), probing or spindle-synchronised motion;
- ``beyond travel``: rs274's path leaves the twin's travel (+-255 mm per axis from the origin);
- ``agree``: same ends, arc centres and turns within 1 um (3 um inch), :mod:`gantry_twin.gcode.oracle`;
- ``differ``: the first disagreement;
- ``on the edge``: the reader refuses it and so does rs274 once every tool is 1e-9 wider (a program
  on the boundary of one of LinuxCNC's cutter compensation rules, which rs274 passes by rounding: it
  converts the table's inches with 0.03937007874016 mm^-1 and reads every radius 4e-14 small);
- ``twin refuses``: the reader's one-line error.

Both read one tool table (cutter compensation takes its diameters): ``--tool-table FILE``, in inches
(rs274's standalone machine units), by default the one rs274 reads when it is given none, LinuxCNC's
sample table :data:`RS274_TOOL_TABLE`; the reader gets it in mm.

Prints the counts (and with ``--list`` one line per program); exits 1 when a program that rs274 runs,
in XY and within the travel, the reader reads differently (a refusal is judged by its line). docs/gcode.md
gives the counts measured.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from collections import Counter
from pathlib import Path

from gantry_twin.gcode import GcodeError, read_program
from gantry_twin.gcode.arcs import MM_PER_INCH
from gantry_twin.gcode.oracle import compare, rs274_available, rs274_path, run_rs274, twin_path
from gantry_twin.gcode.program import TRAVEL_HALF_M
from gantry_twin.gcode.tools import Tool, read_tool_table

DIRECTORIES = ("nc_files", "tests/trajectory-planner/circular-arcs/nc_files")
SUFFIXES = (".ngc", ".nc")
#: The tool table rs274 reads when it is given none (its built-in path; Debian's linuxcnc-uspace), inches.
RS274_TOOL_TABLE = Path("/usr/share/doc/linuxcnc/examples/sample-configs/common/tool.tbl")
#: "On the edge": rs274 refuses the program once every tool's diameter is this much (relative) wider.
EDGE = 1e-9


def programs(checkout: Path) -> list[Path]:
    found = []
    for directory in DIRECTORIES:
        root = checkout / directory
        found += sorted(p for p in root.rglob("*") if p.suffix.lower() in SUFFIXES and p.is_file())
    return found


def tools_in_mm(table: Path) -> dict[int, Tool]:
    """A tool table in inches (rs274's) as the reader takes it (mm)."""
    return {n: dataclasses.replace(t, diameter_m=t.diameter_m * MM_PER_INCH) for n, t in read_tool_table(table).items()}


def rs274_on_the_edge(path: Path, timeout_s: float, table: Path) -> str:
    """rs274's message when it refuses ``path`` with every tool of ``table`` :data:`EDGE` wider ("" when it
    runs it to its end)."""
    with tempfile.TemporaryDirectory(prefix="rs274-study-") as directory:
        wider = Path(directory) / "wider.tbl"
        wider.write_text("".join(f"T{t.number} P{t.pocket} D{t.diameter_m * 1e3 * (1.0 + EDGE)!r}\n"
                                 for t in read_tool_table(table).values()))  # fmt: skip
        oracle = rs274_path(*run_rs274(path, wider, timeout_s=timeout_s))
    return "" if oracle.ok else oracle.message[:100]


def judge(path: Path, timeout_s: float, table: Path | None = None) -> tuple[str, str]:
    """(class, detail) of one program, as the module's docstring says; ``table`` the tool table (inches)."""
    code, output = run_rs274(path, table, timeout_s=timeout_s)
    oracle = rs274_path(code, output)
    if not oracle.ok:
        return "rs274 stops", oracle.message[:100]
    if not oracle.xy_plane or oracle.foreign:
        return "not XY", oracle.foreign or "arcs in another plane"
    half_mm = TRAVEL_HALF_M[0] * 1e3
    if max(abs(v) for v in oracle.extent_mm) > half_mm + 1e-6:
        return "beyond travel", "extent " + " ".join(f"{v:.1f}" for v in oracle.extent_mm) + " mm"
    try:
        tools = tools_in_mm(table) if table is not None else None
        twin = read_program(path, drop_unsupported=True, merge_lines=False, tools=tools)
    except GcodeError as error:
        refusal = str(error).replace(str(path), path.name)
        edge = rs274_on_the_edge(path, timeout_s, table) if table is not None else ""
        if edge:
            return "on the edge", f"{refusal}; rs274 with every tool {EDGE:g} wider: {edge}"
        return "twin refuses", refusal
    result = compare(oracle.points, twin_path(twin))
    if result.agreed:
        return "agree", f"{result.matched} points, worst {result.worst_mm * 1e3:.2f} um"
    return "differ", result.disagreement


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkout", type=Path, help="a LinuxCNC source tree")
    parser.add_argument("--list", action="store_true", help="one line per program")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds rs274 may take per program")
    default = f"default: {RS274_TOOL_TABLE} where it exists"
    parser.add_argument("--tool-table", type=Path, help=f"the tool table both read, inches ({default})")
    args = parser.parse_args(argv)
    table = args.tool_table or (RS274_TOOL_TABLE if RS274_TOOL_TABLE.is_file() else None)
    if table is not None:
        try:
            tools_in_mm(table)
        except GcodeError as error:
            print(f"rs274_study: {error}", file=sys.stderr)
            return 2
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
        kind, detail = judge(path.resolve(), args.timeout, table)
        counts[kind] += 1
        if kind in ("twin refuses", "differ", "not XY", "on the edge"):
            details[
                f"{kind}: {detail.split(': ', 1)[-1] if kind in ('twin refuses', 'on the edge') else detail}"[:110]
            ] += 1
        if args.list:
            print(f"{kind:14} {path.relative_to(args.checkout)}: {detail}")
    ordered = sorted(counts.items(), key=lambda item: (-item[1], item[0]))
    print(f"{len(found)} programs: " + ", ".join(f"{kind} {n}" for kind, n in ordered))
    for detail, n in details.most_common():
        print(f"  {n:3d} x {detail}")
    return 1 if counts["differ"] else 0


if __name__ == "__main__":
    sys.exit(main())
