"""``gantry-twin runs [--prune --keep N [--yes]]``: the runs under runs/, and removing the older ones."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gantry_twin.cli.common import EXIT_OK, PROG, BadInput


def add_arguments(parser: argparse.ArgumentParser, runs_dir: Path) -> None:
    parser.add_argument(
        "--dir", metavar="DIR", type=Path, default=runs_dir, help=f"where runs are (default: {runs_dir})"
    )
    parser.add_argument("--prune", action="store_true", help="remove all but the last --keep runs of each scenario")
    parser.add_argument("--keep", metavar="N", type=int, help="with --prune: runs kept per scenario")
    parser.add_argument("--yes", action="store_true", help="with --prune: really delete (default: only say what)")


def command(args: argparse.Namespace) -> int:
    """List the runs (0); with --prune, say what would go, and with --yes remove it. ``latest``'s target stays."""
    from gantry_twin.outputs.files import remove_tree
    from gantry_twin.outputs.runlist import describe, human_size, list_runs, to_prune

    if args.prune and (args.keep is None or args.keep < 0):
        raise BadInput(f"--keep: --prune needs --keep N, N >= 0, got {args.keep}")
    if not args.prune and (args.keep is not None or args.yes):
        raise BadInput("--keep and --yes go with --prune")
    if not args.dir.is_dir():
        print(f"no runs: {args.dir} does not exist")
        return EXIT_OK
    entries = list_runs(args.dir)
    if not args.prune:
        for e in entries:
            print(describe(e))
        total = sum(e.size_bytes for e in entries)
        compares = sum(e.status == "compare" for e in entries)
        also = f" and {compares} compare{'s' if compares != 1 else ''}" if compares else ""
        print(f"{_runs(len(entries) - compares)}{also}, {human_size(total)} in {args.dir}")
        return EXIT_OK
    doomed = to_prune(entries, args.keep)
    verb = "deleted" if args.yes else "would delete"
    for e in doomed:
        if args.yes:
            remove_tree(e.path)
        print(f"{verb} {describe(e)}")
    freed = human_size(sum(e.size_bytes for e in doomed))
    print(f"{verb} {_runs(len(doomed))} ({freed}); kept the last {args.keep} per scenario and every latest")
    if doomed and not args.yes:
        print(f"{PROG}: dry run: add --yes to delete them", file=sys.stderr)
    return EXIT_OK


def _runs(n: int) -> str:
    return f"{n} run" if n == 1 else f"{n} runs"
