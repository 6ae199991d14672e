"""``validate PROGRAM.ngc`` and the part-program options of ``run`` and ``validate`` (docs/gcode.md)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from gantry_twin.cli.common import DEFAULT_SCENARIO, BadInput
from gantry_twin.gcode.program import GcodeError
from gantry_twin.gcode.reader import TRAVEL_HALF_M
from gantry_twin.gcode.report import validation_lines
from gantry_twin.scenario import load_scenario
from gantry_twin.scenario.files import shipped
from gantry_twin.settings import label_from

#: File names taken as a G-code part program rather than a scenario.
PROGRAM_SUFFIXES = (".ngc", ".nc", ".gcode")


def is_program(path: str | Path) -> bool:
    return Path(path).suffix.lower() in PROGRAM_SUFFIXES


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--drop-unsupported",
        action="store_true",
        help="a part program's Z, spindle and coolant words and drilling cycles' Z part are dropped and counted "
        "(default: refused)",
    )
    parser.add_argument(
        "--subroutine-path",
        action="append",
        default=[],
        metavar="DIR",
        help="a directory searched for a part program's NAME.ngc subroutines before the program's own (repeatable)",
    )
    parser.add_argument(
        "--cnc",
        choices=("twin", "linuxcnc"),
        help="who reads and plans a part program: the twin (default) or LinuxCNC, run headless, whose recorded "
        "commands the twin tracks (docs/linuxcnc.md)",
    )
    parser.add_argument(
        "--cnc-ini",
        metavar="FILE",
        help="with --cnc linuxcnc: a LinuxCNC INI whose [TRAJ], [AXIS_X], [AXIS_Y] and joint limits LinuxCNC plans "
        "with (default: the twin's machine, gantry-twin linuxcnc config)",
    )
    parser.add_argument(
        "--tool-table",
        metavar="FILE",
        help="a LinuxCNC tool table: the diameters (mm) that cutter radius compensation (G41 / G42) uses",
    )


def overrides(args: argparse.Namespace, program: Path | None) -> list[str]:
    """The --set overrides that run a part program in the default scenario with the options given."""
    out = []
    if program is not None:
        out += [f"contour={{type: gcode, file: {json.dumps(str(program))}}}", f"name={label_from(program.stem)}"]
    if getattr(args, "drop_unsupported", False):
        out.append("contour.drop_unsupported=true")
    if getattr(args, "cnc", None):
        out.append(f"contour.cnc={args.cnc}")
    if getattr(args, "cnc_ini", None):
        out.append(f"contour.cnc_ini={json.dumps(str(Path(args.cnc_ini).resolve()))}")
    if getattr(args, "tool_table", None):
        out.append(f"contour.tool_table={json.dumps(str(Path(args.tool_table).resolve()))}")
    if getattr(args, "subroutine_path", None):
        out.append(f"contour.subroutine_path={json.dumps([str(Path(d).resolve()) for d in args.subroutine_path])}")
    return out


def validate_program(path: Path, args: argparse.Namespace) -> None:
    """Read and plan a program without simulating it; print its summary (BadInput: one line, exit 2)."""
    scenario = load_scenario(shipped(DEFAULT_SCENARIO), [*overrides(args, path), *args.overrides])  # named as given
    contour = scenario.contour
    if contour.cnc == "linuxcnc":
        return _validate_with_rs274(path, contour)
    try:
        program = contour.read()
        plan = contour.plan(program=program) if program.moves else None  # nothing in XY: judged, not planned
    except GcodeError as exc:
        raise BadInput(str(exc)) from None
    print("\n".join(validation_lines(program, plan, TRAVEL_HALF_M)), flush=True)


def _validate_with_rs274(path: Path, contour) -> None:
    """``validate --cnc linuxcnc``: the program as LinuxCNC's rs274 reads it (docs/linuxcnc.md); nothing runs."""
    from gantry_twin.cnc.canon import read_canon
    from gantry_twin.cnc.session import LinuxCncError, missing
    from gantry_twin.gcode.geometry import bounding_box

    why = missing()
    if why is not None:
        raise BadInput(f"--cnc linuxcnc: {why}")
    try:
        subroutines = tuple(Path(d) for d in contour.subroutine_path)
        canon = read_canon(path, Path(contour.tool_table) if contour.tool_table else None, subroutines)
    except (GcodeError, LinuxCncError) as exc:
        raise BadInput(str(exc)) from None
    moves = canon.moves
    lines = [f"{path}: LinuxCNC's rs274 reads {len(moves)} XY moves ({sum(m.rapid for m in moves)} rapid)"]
    if moves:
        lo, hi = bounding_box(moves)
        lines.append(
            f"  XY extent: X {lo[0] * 1e3:.3f} .. {hi[0] * 1e3:.3f} mm, Y {lo[1] * 1e3:.3f} .. {hi[1] * 1e3:.3f} mm"
        )
    if canon.unjudged:
        lines.append(f"  {len(canon.unjudged)} spline or other-plane stretches: run, not judged by the part error")
    lines += [f"  message: {m}" for m in canon.messages]
    print("\n".join(lines), flush=True)
