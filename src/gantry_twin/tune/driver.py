"""``gantry-twin tune``: plan -> cluster -> the baseline's runs -> trials as TPE asks for them, one trial per task on
the sweep engine's workers -> DIR/study.db (Optuna's SQLite storage: ``--resume`` continues it, optuna-dashboard
opens it), DIR/trials.parquet (rewritten after each trial), and at the end the results (:mod:`.results`).

A trial's runs go to one worker as one task (:func:`gantry_twin.tune.goals.run_trial`): a worker lost mid-trial
has that task rescheduled by Dask, or, after it kills workers too often, the trial failed; the study goes on.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gantry_twin.outputs.signals import stop_signals_interrupt
from gantry_twin.scenario import ScenarioError
from gantry_twin.sweep.engine import in_order, open_stream
from gantry_twin.tune.goals import TrialRuns, goal_values, run_metrics, run_trial
from gantry_twin.tune.plan import TunePlan
from gantry_twin.tune.results import ATTR_CONSTRAINTS, ATTR_ERROR, ATTR_F, ATTR_METRICS, write_trials

STUDY_FILE = "study.db"
STUDY_NAME = "gantry-twin-tune"
#: Whether a failed trial counts against the budget (its own runs failed; not a trial left by a killed driver).
ATTR_COUNTED = "counted"
#: Study attributes: the baseline's runs, the spec's text digest.
ATTR_BASELINE = "baseline_metrics"


class TuneError(ValueError):
    """The output directory cannot take the study (a study there and no --resume, another spec's study)."""


@dataclass(frozen=True)
class TuneOutcome:
    """What a tune did: the trials counted before (``--resume``) and now, how many failed, its times, s."""

    done_before: int
    ran: int
    failed: int
    wall_time_s: float
    trials_s: float
    study: Any
    baseline: list[dict[str, float] | None]


def storage_url(out: Path) -> str:
    return f"sqlite:///{(Path(out) / STUDY_FILE).resolve()}"


#: The first bytes of an SQLite database (Optuna's storage of a study).
SQLITE_MAGIC = b"SQLite format 3\x00"


def check_out(out: Path, resume: bool) -> None:
    """TuneError when ``out`` holds a study and this is not ``--resume`` (nothing there is replaced), or when the
    study to resume is not a regular file that is an SQLite database (checked before the cluster starts: a junk
    study.db once gave a traceback from SQLAlchemy, exit 1)."""
    from gantry_twin.inputs import InputFileError, check_input_file

    study = Path(out) / STUDY_FILE
    if not (study.exists() or study.is_symlink()):
        return
    if not resume:
        raise TuneError(f"--out {out}: holds a study ({STUDY_FILE}); give --resume to continue it or another --out")
    what = "a tune's study (SQLite), or another --out"
    try:
        check_input_file(study, what)
        with open(study, "rb") as fh:
            head = fh.read(len(SQLITE_MAGIC))
    except InputFileError as exc:
        raise TuneError(f"--resume: {study}: {exc}") from None
    except OSError as exc:
        raise TuneError(f"--resume: {study}: cannot read ({exc.strerror}); give {what}") from None
    if head != SQLITE_MAGIC:
        raise TuneError(f"--resume: {study}: not an SQLite database; give {what}")


def _distributions(plan: TunePlan) -> dict[str, Any]:
    from optuna.distributions import FloatDistribution, IntDistribution

    out: dict[str, Any] = {}
    for d in plan.spec.design:
        if d.integer:
            out[d.label] = IntDistribution(math.ceil(d.low), math.floor(d.high), log=d.log)
        else:
            out[d.label] = FloatDistribution(d.low, d.high, log=d.log)
    return out


def _sampler(plan: TunePlan, seed: int) -> Any:
    """TPE, seeded; the hard goals are constraints each trial sets (``Trial.set_constraint``: f - 1 <= 0 met)."""
    import optuna

    return optuna.samplers.TPESampler(
        seed=seed, n_startup_trials=plan.spec.optimiser.startup_trials, multivariate=True, constant_liar=True
    )


def _fail_stale(study: Any) -> None:
    """Trials left RUNNING by a driver that was killed: failed, and not counted (they will be asked again)."""
    from optuna.trial import TrialState

    for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING, TrialState.WAITING)):
        if trial.state == TrialState.RUNNING:
            study._storage.set_trial_state_values(trial._trial_id, TrialState.FAIL)


def counted(study: Any) -> int:
    """Trials that count against the budget: finished (complete, pruned) or failed by their own runs."""
    from optuna.trial import TrialState

    done = 0
    for t in study.get_trials(deepcopy=False):
        done += t.state in (TrialState.COMPLETE, TrialState.PRUNED) or bool(t.user_attrs.get(ATTR_COUNTED))
    return done


def run_tune(
    plan: TunePlan,
    out: Path,
    trials: int,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    seed: int | None = None,
    progress: bool = False,
    on_trial: Callable[[Any], None] | None = None,
) -> TuneOutcome:
    """Run the trials of the budget not yet counted (``trials`` in all) and write the study and trials.parquet."""
    import optuna
    from optuna.trial import TrialState

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    out = Path(out)
    check_out(out, resume)
    started = time.perf_counter()
    seed = plan.spec.optimiser.seed if seed is None else seed
    soft = plan.spec.soft
    directions = ["minimize"] * len(soft)
    nominal_source = str(plan.cases[0].path)
    baseline_cases = plan.resolved(None)
    ran = failed = 0
    with stop_signals_interrupt(), open_stream(baseline_cases, nominal_source, workers, scheduler) as stream:
        out.mkdir(parents=True, exist_ok=True)
        storage = optuna.storages.RDBStorage(storage_url(out))
        study = optuna.create_study(
            storage=storage,
            sampler=_sampler(plan, seed),
            study_name=STUDY_NAME,
            directions=directions,
            load_if_exists=True,
        )
        baseline = study.user_attrs.get(ATTR_BASELINE)
        if baseline is None:  # the baseline's runs, one task per case, spread over the workers
            args = [(resolved, str(case.path)) for resolved, case in zip(baseline_cases, plan.cases, strict=True)]
            baseline = in_order(stream(run_metrics, args, progress=False, total=len(args)), len(args))
            study.set_user_attr(ATTR_BASELINE, baseline)
            study.set_user_attr("spec_source", plan.source)
        _fail_stale(study)
        done_before = counted(study)
        checks = plan.checks(baseline)
        if not study.trials and plan.spec.optimiser.enqueue_baseline:
            values = plan.baseline_design
            if all(
                v is not None and d.low <= v <= d.high for d, v in zip(plan.spec.design, values.values(), strict=True)
            ):
                study.enqueue_trial(dict(values))
        distributions = _distributions(plan)
        todo = max(0, trials - done_before)
        asked: list[Any] = []

        def designs() -> Iterator[tuple[Any, ...]]:
            made = 0
            while made < todo:
                trial = study.ask(distributions)
                try:
                    cases = plan.resolved(dict(trial.params))
                except ScenarioError as exc:  # a combination of the design the schema refuses: that trial fails
                    trial.set_user_attr(ATTR_ERROR, str(exc))
                    trial.set_user_attr(ATTR_COUNTED, True)
                    study.tell(trial, state=TrialState.FAIL)
                    made += 1
                    continue
                asked.append(trial)
                made += 1
                yield (cases, nominal_source, checks, plan.nominal)

        marks = time.perf_counter()
        results = stream(run_trial, designs(), progress=progress, desc="tune", total=trials, initial=done_before)
        for index, result, error in results:
            trial = asked[index]
            ran += 1
            frozen = _tell(study, trial, result, error, checks, len(soft))
            failed += frozen.state == TrialState.FAIL
            write_trials(plan, study, out)
            if on_trial is not None:
                on_trial(frozen)
        write_trials(plan, study, out)
    return TuneOutcome(
        done_before, ran, failed, time.perf_counter() - started, time.perf_counter() - marks, study, baseline
    )


def _tell(study: Any, trial: Any, result: TrialRuns | None, error: Exception | None, checks: list, soft: int) -> Any:
    """Record a trial's runs and goals and tell the study: complete, pruned (a hard goal broken on the nominal
    plant) or failed (its worker died too often, or the task raised)."""
    from optuna.trial import TrialState

    if error is not None:
        trial.set_user_attr(ATTR_ERROR, f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}")
        trial.set_user_attr(ATTR_COUNTED, True)
        return study.tell(trial, state=TrialState.FAIL)
    f = goal_values(checks, result.metrics)
    hard = [v for v, c in zip(f, checks, strict=True) if c.kind == "hard"]
    trial.set_user_attr(ATTR_F, f)
    trial.set_user_attr(ATTR_METRICS, result.metrics)
    trial.set_user_attr("wall_time_s", result.wall_time_s)
    constraints = [(v if v is not None else 0.0) - 1.0 for v in hard]
    trial.set_user_attr(ATTR_CONSTRAINTS, constraints)
    for c, value in zip([c for c in checks if c.kind == "hard"], constraints, strict=True):
        trial.set_constraint(c.name, value)
    values = [v for v, c in zip(f, checks, strict=True) if c.kind == "soft"]
    if result.pruned:
        if soft == 1 and values[0] is not None:
            trial.report(values[0], 0)
        return study.tell(trial, state=TrialState.PRUNED)
    return study.tell(trial, values if soft > 1 else values[0])
