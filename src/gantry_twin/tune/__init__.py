"""Tuning a controller on the twin (``gantry-twin tune``, docs/tune.md), robust over an ensemble of plants.

* :mod:`.spec`: the tune file (design variables and ranges, scenarios, the ensemble, goals), validated like a
  scenario file.
* :mod:`.plan`: every run a trial makes, checked before anything runs.
* :mod:`.goals`: goals normalised as systune's (f <= 1 met) and a trial's runs on a worker, the nominal plant
  first.
* :mod:`.driver`: Optuna's TPE with the hard goals as constraints, in a SQLite study, trials on the sweep engine.
* :mod:`.results`: the best design, tuned.yaml, trials.parquet, summary.md, figures, the compare pair.
"""

from gantry_twin.tune.driver import STUDY_FILE, TuneError, TuneOutcome, check_out, counted, run_tune
from gantry_twin.tune.plan import Case, TunePlan, plan_tune
from gantry_twin.tune.results import best_trial, feasible, write_results
from gantry_twin.tune.spec import TuneSpec, load_tune, parse_tune, tune_file, tunes_dir

__all__ = [
    "STUDY_FILE",
    "Case",
    "TuneError",
    "TuneOutcome",
    "TunePlan",
    "TuneSpec",
    "best_trial",
    "check_out",
    "counted",
    "feasible",
    "load_tune",
    "parse_tune",
    "plan_tune",
    "run_tune",
    "tune_file",
    "tunes_dir",
    "write_results",
]
