"""``gantry-twin sweep FILE [--out DIR] [--workers N | --scheduler ADDRESS] [--resume | --fresh]`` (docs/sweeps.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gantry_twin.cli.common import EXIT_OK, EXIT_RUN_FAILED, PROG, BadInput, checked_out, failed, writable_out
from gantry_twin.cli.progress import add_progress_arguments, progress_wanted
from gantry_twin.scenario import ScenarioError


def add_arguments(parser: argparse.ArgumentParser, runs_dir: Path) -> None:
    parser.add_argument("file", help="sweep YAML file or shipped sweep name (sweeps/)")
    parser.add_argument(
        "--out", metavar="DIR", type=Path, help=f"output directory (default: {runs_dir}/sweeps/<file>/)"
    )
    parser.set_defaults(runs_dir=runs_dir)
    where = parser.add_mutually_exclusive_group()
    where.add_argument(
        "--workers", metavar="N", type=int, help="local worker processes, at most the machine's cores (the default)"
    )
    where.add_argument(
        "--scheduler", metavar="ADDRESS", help="use the running Dask cluster at ADDRESS (tcp://host:8786)"
    )
    again = parser.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="run only the points DIR/results.parquet lacks")
    again.add_argument("--fresh", action="store_true", help="move an earlier sweep's files in DIR aside, then run")
    add_progress_arguments(parser)


def command(args: argparse.Namespace) -> int:
    """Run ``sweep``: 0 when it completed (some points may have failed), 1 when every point run failed or the sweep
    itself did, 2 for bad input (the file, --out, --workers, --scheduler, results of another sweep to resume)."""
    from gantry_twin.sweep import (
        ClusterError,
        existing_results,
        load_sweep,
        plan_sweep,
        run_sweep,
        set_aside,
        sweep_file,
    )
    from gantry_twin.sweep.engine import check_scheduler, check_workers

    try:
        check_workers(args.workers)
        check_scheduler(args.scheduler)
    except ClusterError as exc:
        raise BadInput(str(exc)) from None
    path = sweep_file(args.file)
    out = checked_out(args.out or args.runs_dir / "sweeps" / path.stem)
    plan = plan_sweep(load_sweep(path), str(path))  # every point checked before anything runs
    with writable_out(out):  # before the cluster starts (a read-only --out found in milliseconds, not after)
        if args.fresh and out.is_dir():
            moved = set_aside(out)
            if moved:
                print(f"{PROG}: {moved}", file=sys.stderr, flush=True)
        elif not args.resume and existing_results(out):
            again = f"{PROG} sweep {args.file}" + (f" --out {args.out}" if args.out else "")
            raise BadInput(
                f"--out {out}: holds an earlier sweep's results.parquet; to finish it: {again} --resume; "
                f"to start afresh (the earlier files moved aside): {again} --fresh"
            )
        try:
            done = run_sweep(plan, out, args.workers, args.scheduler, args.resume, progress_wanted(args))
        except ClusterError as exc:
            raise BadInput(str(exc)) from None
        except ScenarioError:  # e.g. --resume on another sweep's results: refused before anything runs (exit 2)
            raise
        except Exception as exc:
            return failed("sweep", exc)
    print(
        f"{done.total} points: {done.done_before} done before, {done.ran} run now ({done.failed} failed) "
        f"in {done.wall_time_s:.1f} s ({done.startup_s:.1f} s starting the workers); results in {done.results}",
        flush=True,
    )
    if done.ran and done.failed == done.ran:
        print(f"{PROG}: sweep failed: every point run failed (see the error column of {done.results})", file=sys.stderr)
        return EXIT_RUN_FAILED
    return EXIT_OK
