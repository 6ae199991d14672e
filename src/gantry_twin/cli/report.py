"""``gantry-twin report``: the paper's matrix on the rig twin and the ideal twin, a Markdown report with figures
(docs/cli.md)."""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from pathlib import Path

from gantry_twin.cli.common import EXIT_OK, PROG, BadInput, failed, writable_out
from gantry_twin.cli.progress import add_progress_arguments, progress_wanted
from gantry_twin.run import package_version


def add_arguments(parser: argparse.ArgumentParser, runs_dir: Path) -> None:
    default_report = runs_dir / "report"
    parser.add_argument(
        "--out", metavar="DIR", type=Path, default=default_report, help=f"output directory (default: {default_report}/)"
    )
    parser.add_argument(
        "--workers", metavar="N", type=int, default=None, help="parallel worker processes (default: os.cpu_count())"
    )
    parser.add_argument("--jobs", metavar="N", type=int, default=None, help=argparse.SUPPRESS)  # deprecated: --workers
    parser.add_argument(
        "--rig",
        metavar="FILE",
        type=Path,
        default=None,
        help="the rig twin's plant from a calibration: FILE's 'overrides' (a list of field=value strings, "
        "the fit.json that gantry-twin calibrate writes), after each run's own",
    )
    parser.add_argument(
        "--no-ideal",
        action="store_true",
        help="skip the ideal twin's runs (plant.model=paper) and the paper / rig twin / ideal twin section",
    )
    add_progress_arguments(parser)


def command(args: argparse.Namespace) -> int:
    """Run the matrix (and the ideal twin's) and write the report. Exit code."""
    started = time.monotonic()

    workers, flag = args.workers, "--workers"
    if args.jobs is not None:
        print(f"{PROG}: warning: --jobs is deprecated, use --workers", file=sys.stderr)
        if workers is None:
            workers, flag = args.jobs, "--jobs"
    if workers is not None and workers < 1:
        raise BadInput(f"{flag}: must be a positive integer, got {workers}")
    with writable_out(args.out):  # before the matrix is checked or any run starts (even imported)
        from gantry_twin.reports import rig as rig_report
        from gantry_twin.reports.paper import paper_matrix, provenance, run_matrix, write_report

        rig = rig_report.load_rig(args.rig) if args.rig is not None else ()
        cases = paper_matrix((*args.overrides, *rig))  # validates every scenario before anything runs
        plant = rig_report.plant_label(cases[0])
        # The ideal twin beside the rig twin, unless told not to or the matrix runs on the ideal twin already.
        ideal = (
            []
            if args.no_ideal or rig_report.is_ideal(cases[0])
            else rig_report.rig_cases(paper_matrix(args.overrides, labels=rig_report.LABELS), rig_report.IDEAL)
        )
        try:
            results = run_matrix([*cases, *ideal], jobs=workers or os.cpu_count() or 1, progress=progress_wanted(args))
            results, ideal_results = results[: len(cases)], results[len(cases) :]
            appendix = (
                rig_report.section(ideal_results, results, rig, args.out, args.overrides, plant)
                if ideal_results
                else []
            )
            made_by = provenance(shlex.join([PROG, *args.argv]), time.monotonic() - started, package_version())
            path = write_report(results, args.out, (*args.overrides, *rig), appendix, made_by, plant)
        except Exception as exc:
            return failed("report", exc)
    print(f"report written to {path}")
    return EXIT_OK
