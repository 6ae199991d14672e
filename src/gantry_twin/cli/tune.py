"""``gantry-twin tune SPEC --out DIR``: tune a controller's design variables on the twin, robust over an ensemble
of plants, with Optuna's TPE on the sweep engine's Dask workers (docs/tune.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gantry_twin.cli.common import EXIT_OK, EXIT_RUN_FAILED, BadInput, checked_out, writable_out
from gantry_twin.sweep.engine import ClusterError, check_scheduler, check_workers
from gantry_twin.tune import TuneError, best_trial, check_out, load_tune, plan_tune, run_tune, tune_file, write_results
from gantry_twin.tune.spec import TRIALS_MAX


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``tune`` to the subcommands."""
    parser = sub.add_parser("tune", help="tune a controller, robust over an ensemble of plants (docs/tune.md)")
    add_arguments(parser)
    parser.set_defaults(func=command)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("spec", help="tune YAML file or shipped tune name (tunes/)")
    parser.add_argument("--out", metavar="DIR", type=Path, help="output directory (default: runs/tunes/<spec>/)")
    parser.add_argument("--trials", metavar="N", type=int, help="trials in all (default: the spec's optimiser.trials)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", metavar="N", type=int, help="local worker processes (default: the machine's cores)")
    where.add_argument(
        "--scheduler", metavar="ADDRESS", help="use the running Dask cluster at ADDRESS (tcp://host:8786)"
    )
    parser.add_argument("--resume", action="store_true", help="continue the study in DIR (its trials count)")
    parser.add_argument("--seed", metavar="S", type=int, help="the sampler's seed (default: the spec's optimiser.seed)")
    parser.add_argument(
        "--progress", action=argparse.BooleanOptionalAction, default=None, help="one line per trial on stderr"
    )


def command(args: argparse.Namespace) -> int:
    """Check the spec and the options (exit 2, nothing written), tune, write DIR's files, print the best design."""
    if args.trials is not None and not 1 <= args.trials <= TRIALS_MAX:
        raise BadInput(f"--trials: must be an integer in [1, {TRIALS_MAX}], got {args.trials}")
    if args.seed is not None and not 0 <= args.seed < 2**32:
        raise BadInput(f"--seed: must be an integer in [0, 2**32 - 1], got {args.seed}")
    try:
        check_workers(args.workers)
        check_scheduler(args.scheduler)
    except ClusterError as exc:
        raise BadInput(str(exc)) from None
    path = tune_file(args.spec)
    plan = plan_tune(load_tune(path), str(path))  # every case checked before anything runs
    out = checked_out(args.out or Path("runs") / "tunes" / path.stem)
    try:
        check_out(out, args.resume)
    except TuneError as exc:
        raise BadInput(str(exc)) from None
    trials = args.trials or plan.spec.optimiser.trials
    progress = sys.stderr.isatty() if args.progress is None else args.progress

    def show(trial: object) -> None:
        if progress:
            f = trial.user_attrs.get("f") or []
            shown = " ".join("-" if v is None else f"{v:.3g}" for v in f)
            print(f"{trial.number:4d} {trial.state.name.lower():8s} f {shown}", file=sys.stderr, flush=True)

    try:
        with writable_out(out):  # before the cluster starts: a read-only --out found in milliseconds, not after it
            outcome = run_tune(plan, out, trials, args.workers, args.scheduler, args.resume, args.seed, False, show)
    except ClusterError as exc:
        raise BadInput(str(exc)) from None
    except OSError as exc:
        raise BadInput(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    checks = plan.checks(outcome.baseline)
    note = f"Ran {outcome.ran} trials ({outcome.done_before} before) in {outcome.trials_s:.1f} s."
    best = write_results(plan, outcome.study, outcome.baseline, checks, out, note=note)
    print(
        f"{outcome.ran} trials now, {outcome.done_before} before, {outcome.failed} failed; {outcome.wall_time_s:.1f} s"
    )
    if best is None or best_trial(plan, outcome.study) is None:
        print(f"no trial met every hard goal; see {out}/summary.md", file=sys.stderr)
        return EXIT_RUN_FAILED
    print(best_line(plan.baseline_design, best.number, best.params))
    for name, value in best.params.items():
        print(f"  {name} = {value:.6g}")
    print(f"results in {out}/ (tuned.yaml, trials.parquet, summary.md, study.db, baseline/, tuned/)")
    return EXIT_OK


def best_line(baseline_design: dict[str, float | None], number: int, params: dict[str, float]) -> str:
    """``best: trial N``, saying so when the best design is the scenarios' own values (the baseline, enqueued first:
    no trial improved on it)."""
    same = all(params.get(label) == value for label, value in baseline_design.items())
    return f"best: trial {number}" + (" (the scenarios' own values: no trial improved on them)" if same else "")
