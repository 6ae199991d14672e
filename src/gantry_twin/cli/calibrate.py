"""``gantry-twin calibrate SPEC --out DIR``: fit the plant to a machine's measured contour errors (docs/cli.md)."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from gantry_twin.calibration import calibration_file, load_calibration, plan
from gantry_twin.calibration.driver import FIT_FILE, run_calibration
from gantry_twin.calibration.fit import Evaluation
from gantry_twin.calibration.spec import EVALUATIONS_MAX
from gantry_twin.cli.common import writable_out
from gantry_twin.settings import shorten
from gantry_twin.sweep.engine import ClusterError, check_scheduler, check_workers


class CalibrateError(ValueError):
    """Bad command-line input of ``calibrate`` (exit code 2)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("spec", help="calibration YAML file or shipped calibration name (calibrations/)")
    parser.add_argument("--out", metavar="DIR", type=Path, help="output directory (default: runs/calibrations/<spec>/)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument(
        "--workers", metavar="N", type=int, help="local worker processes, at most the machine's cores (the default)"
    )
    where.add_argument(
        "--scheduler", metavar="ADDRESS", help="use the running Dask cluster at ADDRESS (tcp://host:8786)"
    )
    parser.add_argument("--evaluations", metavar="N", type=int, help="the optimiser's budget instead of the spec's")
    parser.add_argument(
        "--progress", action=argparse.BooleanOptionalAction, default=None, help="one line per evaluation on stderr"
    )


def command(args: argparse.Namespace) -> int:
    """Check the spec and the options (exit 2, nothing written), fit, write DIR's files, print the fit."""
    try:
        return _calibrate(args)
    except CalibrateError as exc:
        print(f"gantry-twin: error: {exc}", file=sys.stderr)
        return 2


def _calibrate(args: argparse.Namespace) -> int:
    if args.evaluations is not None and not 1 <= args.evaluations <= EVALUATIONS_MAX:
        shown = shorten(str(args.evaluations), 24)
        raise CalibrateError(f"--evaluations: must be 1 to {EVALUATIONS_MAX} (the spec's limit), got {shown}")
    try:  # before the spec is read or any cluster started (a typo must not start 10**20 processes)
        check_workers(args.workers)
        check_scheduler(args.scheduler)
    except ClusterError as exc:
        raise CalibrateError(str(exc)) from None
    path = calibration_file(args.spec)
    made = plan(load_calibration(path), str(path))  # every target's scenario checked before anything runs
    out = args.out or Path("runs") / "calibrations" / path.stem
    progress = sys.stderr.isatty() if args.progress is None else args.progress
    made_by = f"gantry-twin calibrate {shlex.quote(str(args.spec))} --out {shlex.quote(str(out))}"
    if args.evaluations is not None:
        made_by += f" --evaluations {args.evaluations}"

    def show(e: Evaluation) -> None:
        if progress:
            values = " ".join(f"{k}={v:.4g}" for k, v in e.values.items())
            print(f"{e.index + 1:4d} cost {e.cost:.5f} | {values}", file=sys.stderr, flush=True)

    with writable_out(out):  # before the cluster starts; removed again, empty, if the cluster refuses
        try:
            fit = run_calibration(made, out, made_by, args.workers, args.scheduler, args.evaluations, show)
        except ClusterError as exc:
            raise CalibrateError(str(exc)) from None
        except OSError as exc:
            raise CalibrateError(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    best = fit.best
    print(f"{len(fit.evaluations)} evaluations in {fit.wall_time_s:.1f} s; best #{best.index} cost {best.cost:.5f}")
    for name, value in best.values.items():
        print(f"  {name} = {value:.6g}")
    for i, (target, got) in enumerate(zip(made.spec.targets, best.numbers, strict=True)):
        have = "failed" if got is None else f"{got[0]:.3f} / {got[1]:.3f}"
        want = " / ".join("-" if v is None else f"{v:g}" for v in (target.rms_um, target.max_um))
        print(f"  {target.name(i)}: rms / max twin {have} um, measured {want}")
    print(f"results in {out}/ ({FIT_FILE}, evaluations.jsonl, plant.xml)")
    return 0
