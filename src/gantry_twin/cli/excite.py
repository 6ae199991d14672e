"""``gantry-twin excite --out DIR``: write an identification trajectory and run it on the twin (docs/logs.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gantry_twin.cli.common import PROG, BadInput, writable_out
from gantry_twin.plant.model import Payload, Plant
from gantry_twin.sysid.logs import write_columns, write_log
from gantry_twin.sysid.trajectory import design, log_of, run_on_twin, trajectory_table, with_plateaus


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", metavar="DIR", type=Path, required=True, help="output directory")
    parser.add_argument("--duration-s", type=float, default=20.0, help="length of the trajectory, s (default 20)")
    parser.add_argument("--fade-s", type=float, default=1.0, help="fade in and out, s (default 1)")
    parser.add_argument(
        "--payload-kg", type=float, default=0.0, help="payload of the twin that runs it, kg (default 0)"
    )
    parser.add_argument("--plant", metavar="XML", type=Path, help="the twin's MJCF (e.g. an identified plant.xml)")
    parser.add_argument(
        "--plateaus",
        action="store_true",
        help="append constant-velocity plateaus (the steady friction curve: identify --friction lugre)",
    )
    parser.add_argument("--no-run", action="store_true", help="write the trajectory only")


def command(args: argparse.Namespace) -> int:
    """Write DIR/trajectory.csv and (unless --no-run) DIR/log.parquet from the twin. Exit code."""
    from gantry_twin.loop.trace import SimulationError

    out: Path = args.out
    try:
        path = design(args.duration_s, args.fade_s)
        path = with_plateaus(path) if args.plateaus else path
        payload = Payload(mass_kg=args.payload_kg)
        try:
            plant = Plant(payload, model_path=args.plant)
        except (ValueError, KeyError) as exc:
            raise ValueError(f"--plant {args.plant}: not a gantry model ({str(exc).splitlines()[0]})") from None
    except ValueError as exc:  # a bad option, or a --plant file that is not a gantry model
        raise BadInput(str(exc).splitlines()[0]) from None
    with writable_out(out):  # before the trajectory is written or run
        try:
            write_columns(out / "trajectory.csv", trajectory_table(path, plant.timestep_s))
            print(f"trajectory ({path.duration_s:g} s) in {out / 'trajectory.csv'}")
            if args.no_run:
                return 0
            trace = run_on_twin(path, plant, prog=PROG)  # says so if its loop compiles first
            write_log(out / "log.parquet", *log_of(trace))
        except OSError as exc:
            raise BadInput(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
        except SimulationError as exc:
            print(f"{PROG}: run failed: {exc}", file=sys.stderr)
            return 1
    print(f"log of the twin running it in {out / 'log.parquet'}")
    return 0
