"""``gantry-twin linuxcnc config [SCENARIO] --out DIR``: a LinuxCNC configuration of the twin's machine
(docs/linuxcnc.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gantry_twin.cli.common import EXIT_OK, PROG, BadInput, checked_out
from gantry_twin.cnc.config import config_files, machine_for
from gantry_twin.outputs.files import atomic_write_text
from gantry_twin.scenario import load_scenario
from gantry_twin.scenario.files import shipped
from gantry_twin.scenario.schema import GcodeSpec


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``linuxcnc`` (and its ``config``) to the subcommands."""
    parser = sub.add_parser("linuxcnc", help="LinuxCNC drives the twin: its configuration (docs/linuxcnc.md)")
    actions = parser.add_subparsers(dest="action", required=True, metavar="{config}", parser_class=type(parser))
    config = actions.add_parser("config", help="write a LinuxCNC INI and HAL file of the twin's XY machine")
    config.add_argument(
        "scenario", nargs="?", help="a scenario whose part-program limits (contour.limits) LinuxCNC plans with"
    )
    config.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scenario field (repeatable)")  # fmt: skip
    config.add_argument("--out", metavar="DIR", type=Path, required=True, help="the configuration's directory")
    config.set_defaults(func=command)


def command(args: argparse.Namespace) -> int:
    """Write DIR/gantry-twin.ini, .hal and .tbl (each replaced whole); 0."""
    limits = None
    if args.scenario is not None or args.overrides:
        scenario = load_scenario(args.scenario or shipped("no_load_circle"), args.overrides)
        if isinstance(scenario.contour, GcodeSpec) and scenario.contour.limits is not None:
            limits = scenario.contour.limits.limits()
    out = checked_out(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        files = config_files(machine_for(limits))
        for name, text in files.items():
            atomic_write_text(out / name, text)
    except OSError as exc:
        raise BadInput(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    print(f"LinuxCNC configuration of the twin's machine in {out}/ ({', '.join(files)}); run it with "
          f"`linuxcnc {out / 'gantry-twin.ini'}`, or give the INI to `gantry-twin run PROGRAM --cnc linuxcnc "
          "--cnc-ini FILE`")  # fmt: skip
    return EXIT_OK


def announce(scenario: object, wanted: bool) -> None:
    """With progress wanted: one line before LinuxCNC runs a part program (it runs at the wall clock's pace)."""
    contour = getattr(scenario, "contour", None)
    if wanted and isinstance(contour, GcodeSpec) and contour.cnc == "linuxcnc":
        print(f"{PROG}: LinuxCNC runs {contour.file} headless, in real time (docs/linuxcnc.md) ...", file=sys.stderr)
