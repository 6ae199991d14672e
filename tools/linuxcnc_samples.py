"""Run LinuxCNC's own sample programs that the twin's reader refuses through ``gantry-twin run --cnc linuxcnc``.

    PYTHONPATH=src python tools/linuxcnc_samples.py [DIR] [--max-seconds 60] [--run]

DIR: a directory of LinuxCNC programs (default: Debian's
``/usr/share/linuxcnc/ncfiles``; LinuxCNC's programs are GPL-2 and are not
copied into this repository). For each ``.ngc`` it prints: whether the twin's
reader takes it (``--drop-unsupported``) or its one-line refusal; whether
LinuxCNC's ``rs274`` runs it to its end; its XY extent against the travel;
and, with ``--run``, for each program the twin refuses, rs274 runs, within
the travel and of at most ``--max-seconds`` at its feeds: the exit code of
``gantry-twin run PROGRAM --cnc linuxcnc`` and its part error. docs/linuxcnc.md.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from gantry_twin.cnc.canon import read_canon
from gantry_twin.cnc.config import twin_machine
from gantry_twin.cnc.offline import START_S, TIMEOUT_FACTOR, timeout_for
from gantry_twin.cnc.session import LinuxCncError
from gantry_twin.gcode.geometry import bounding_box
from gantry_twin.gcode.program import GcodeError
from gantry_twin.gcode.reader import read_program
from gantry_twin.gcode.tools import read_tool_table

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory", nargs="?", default="/usr/share/linuxcnc/ncfiles", type=Path)
    parser.add_argument("--max-seconds", type=float, default=60.0, help="longest program run (at its feeds)")
    parser.add_argument("--run", action="store_true", help="run the candidates through --cnc linuxcnc")
    parser.add_argument("--tool-table", type=Path, help="a LinuxCNC tool table (mm) for the reader and LinuxCNC")
    args = parser.parse_args()
    machine = twin_machine()
    (x0, x1), (y0, y1) = machine.travel_mm
    ran = failed = 0
    table_option = ["--tool-table", str(args.tool_table)] if args.tool_table else []
    for program in sorted(args.directory.glob("*.ngc")):
        try:
            read_program(
                program, drop_unsupported=True, tools=read_tool_table(args.tool_table) if args.tool_table else {}
            )
            twin = "reads"
        except GcodeError as exc:
            twin = f"refuses: {str(exc).split(': ', 1)[1][:70]}"
        except Exception as exc:  # noqa: BLE001 -- a study: say what happened and go on
            twin = f"raised {type(exc).__name__}"
        try:
            canon = read_canon(program, args.tool_table)
        except (GcodeError, LinuxCncError) as exc:
            print(f"{program.name:28s} twin {twin:80s} rs274: {str(exc)[:60]}")
            continue
        moves = canon.moves
        if not moves:
            print(f"{program.name:28s} twin {twin:80s} rs274: no XY move")
            continue
        lo, hi = bounding_box(moves)
        inside = lo[0] * 1e3 >= x0 and hi[0] * 1e3 <= x1 and lo[1] * 1e3 >= y0 and hi[1] * 1e3 <= y1
        seconds = (timeout_for(canon, machine) - START_S) / TIMEOUT_FACTOR
        line = f"{program.name:28s} twin {twin:80s} rs274: {len(moves)} moves, {seconds:6.1f} s"
        line += "" if inside else ", beyond the travel"
        if args.run and twin != "reads" and inside and seconds <= args.max_seconds:
            ran += 1
            with tempfile.TemporaryDirectory() as tmp:
                out = Path(tmp) / "run"
                done = subprocess.run(
                    [sys.executable, "-m", "gantry_twin", "run", str(program), "--cnc", "linuxcnc", "--out", str(out),
                     "--no-plots", "--no-progress", *table_option],
                    capture_output=True, text=True, cwd=ROOT, timeout=args.max_seconds * TIMEOUT_FACTOR + 600,
                )  # fmt: skip
                if done.returncode == 0:
                    part = json.loads((out / "summary.json").read_text())["part_error"]
                    line += f"; --cnc linuxcnc: exit 0, part error max {part['max_um']:.1f} um"
                else:
                    failed += 1
                    line += f"; --cnc linuxcnc: exit {done.returncode}: {done.stderr.strip()[-120:]}"
        print(line, flush=True)
    if args.run:
        print(f"{ran} programs run through LinuxCNC, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
