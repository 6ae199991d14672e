"""``gantry-twin compare RUN RUN... [--out DIR]``: runs side by side, their plots overlaid (docs/cli.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gantry_twin.cli.common import writable_out
from gantry_twin.outputs.files import atomic_write_dir, atomic_write_text
from gantry_twin.outputs.rundirs import new_run_dir
from gantry_twin.reports.compare import (
    DEFAULT_SUBDIR,
    CompareError,
    as_json,
    labels,
    load_run,
    markdown,
    program_plan,
    table,
)


def add_arguments(parser: argparse.ArgumentParser, runs_dir: Path) -> None:
    """compare's arguments (``runs_dir``: the command line's runs/ directory, for the default --out)."""
    parser.add_argument("runs", nargs="+", metavar="RUN", help="run directory, runs/<name>/latest or runs/<name>")
    default = runs_dir / DEFAULT_SUBDIR
    parser.add_argument(
        "--out", metavar="DIR", type=Path, help=f"output directory (default: a new {default}/<UTC time>-<id>/)"
    )
    parser.set_defaults(runs_dir=runs_dir)


def command(args: argparse.Namespace) -> int:
    """Run ``compare``: CompareError on bad input (the command line exits 2), 0 when written."""
    if len(args.runs) < 2:
        raise CompareError(f"compare needs two runs or more, got one: {args.runs[0]}")
    out = args.out if args.out is not None else new_run_dir(args.runs_dir / DEFAULT_SUBDIR)
    with writable_out(out):  # before the runs are read; removed again, empty, if they are refused
        from gantry_twin.outputs.plots import draw, read_series

        runs = [load_run(arg, f"#{i + 1}") for i, arg in enumerate(args.runs)]
        rows, notes = table(runs)
        drawn = []
        for run, label in zip(runs, labels(runs), strict=True):
            plan, note = program_plan(run)
            if note is not None:
                notes.append(note)
            try:
                series = read_series(run.directory, run.summary, label, plan)
            except Exception as exc:  # a damaged trace: the table does not need it
                notes.append(
                    f"{run.column} ({run.directory}): trace.parquet unreadable ({type(exc).__name__}), not in the plots"
                )
                continue
            if series is None:
                notes.append(f"{run.column} ({run.directory}): no trace.parquet, not in the plots")
            else:
                drawn.append(series)
        text = markdown(runs, rows, notes)
        try:
            atomic_write_text(out / "compare.md", text)
            atomic_write_text(out / "compare.json", as_json(runs, rows, notes))
            figures: list[str] = []
            if drawn:
                atomic_write_dir(out / "plots", lambda tmp: figures.extend(draw(drawn, tmp)))
        except OSError as exc:
            raise CompareError(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    print(text, end="")
    written = ["compare.md", "compare.json"] + [f"plots/{f}" for f in figures]
    print(f"written to {out}/ ({', '.join(written)})", flush=True)
    if notes:
        for note in notes:
            print(f"gantry-twin: note: {note}", file=sys.stderr)
    return 0
