"""The tune file: the controller's design variables and ranges, the scenarios, the ensemble of plants, the goals
(docs/tune.md).

Validated on the package's one pydantic base (:class:`gantry_twin.settings.Model`,
unknown keys rejected) and reported as the scenario files are: a
:class:`~gantry_twin.scenario.ScenarioError`, one line naming the file, the
field and what is allowed. Whether the design fields, the ensemble and the
goals' settings make valid scenarios is checked when the tune is planned
(:mod:`gantry_twin.tune.plan`), before anything runs or is written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import ValidationError, model_validator

from gantry_twin.inputs import InputFileError, read_input_file
from gantry_twin.scenario import ScenarioError, parse_yaml, scenarios_dir
from gantry_twin.scenario.errors import raise_validation
from gantry_twin.settings import Count, Model, Range, Real, fmt, label_from, rule
from gantry_twin.sweep.spec import field_path

#: Largest budget (trials), and the most scenarios, ensemble members, design variables and goals.
TRIALS_MAX = 100000
SCENARIOS_MAX = 16
MEMBERS_MAX = 32
DESIGN_MAX = 16
GOALS_MAX = 16

#: The metrics a goal can bound, each of one run, worst over the goal's runs (docs/tune.md):
METRICS: dict[str, str] = {
    "contour_rms_um": "rms of the contour error over the metric window, um",
    "contour_max_um": "max |contour error| over the metric window, um",
    "saturated_fraction": "fraction of the run's samples with u at its limit, the larger axis",
    "end_stop_contacts": "end-stop contacts in the run, both axes",
    "du_rms_v": "rms of u's sample-to-sample change over the metric window, the larger axis, V",
    "alarms": "health alarms in the run (0 when the monitor is off)",
}


class ScenarioRef(Model):
    """One scenario to judge on: a shipped name or a file relative to the tune file, and what to set on it."""

    scenario: str
    set: dict[str, Any] = {}
    label: str | None = None

    @model_validator(mode="after")
    def _check(self) -> ScenarioRef:
        for key in self.set:
            field_path(key, f"set.{key}")
        return self

    @property
    def name(self) -> str:
        return self.label or label_from(Path(self.scenario).stem)


class Member(Model):
    """One plant of the ensemble: a name and the scenario fields it sets (plant.model, payload.mass_kg, ...)."""

    name: str
    set: dict[str, Any] = {}

    @model_validator(mode="after")
    def _check(self) -> Member:
        for key in self.set:
            field_path(key, f"set.{key}")
        return self


class Design(Model):
    """One design variable: the scenario field it sets (a vector's component by its index, e.g.
    ``controller.options.gains.lambda_1_s.0``), its range, log scale or not, integer or not."""

    field: str
    low: Real
    high: Real
    log: bool = False
    integer: bool = False
    name: str | None = None

    @model_validator(mode="after")
    def _check(self) -> Design:
        field_path(self.field, "field")
        if not self.low < self.high:
            raise rule("high", f"the range is empty: low must be below high, got [{fmt(self.low)}, {fmt(self.high)}]")
        if self.log and self.low <= 0:
            raise rule("low", f"a log-scale range must be above 0, got low {fmt(self.low)}")
        return self

    @property
    def label(self) -> str:
        return self.name or self.field


class Goal(Model):
    """One goal, normalised as systune's: f = worst / limit over its runs (f = 1 + worst for a limit of 0), f <= 1
    met. soft: minimised; hard: a constraint. relative: the limit is a multiple of the baseline design's worst.
    set / members: the goal is judged on extra runs with these fields set (e.g. one more sample of delay), on the
    nominal member, on all, or on the members named."""

    metric: str
    limit: Range(0.0, None)
    kind: Literal["soft", "hard"] = "hard"
    name: str | None = None
    relative: bool = False
    set: dict[str, Any] = {}
    members: Literal["all", "nominal"] | list[str] = "all"

    @model_validator(mode="after")
    def _check(self) -> Goal:
        if self.metric not in METRICS:
            raise rule("metric", f"unknown metric {self.metric!r}; one of {', '.join(METRICS)}")
        if self.relative and self.limit == 0:
            raise rule("limit", "a relative limit must be above 0 (a multiple of the baseline's value)")
        for key in self.set:
            field_path(key, f"set.{key}")
        return self

    @property
    def label(self) -> str:
        return self.name or self.metric


class Optimiser(Model):
    """TPE (Optuna) with the hard goals as constraints; its random start, its seed."""

    trials: Count(1, TRIALS_MAX) = 100
    startup_trials: Count(1, TRIALS_MAX) = 10
    seed: Count(0, 2**32 - 1) = 0
    enqueue_baseline: bool = True


class TuneSpec(Model):
    """A whole tune file."""

    description: str = ""
    set: dict[str, Any] = {}
    scenarios: list[ScenarioRef]
    ensemble: list[Member] = [Member(name="nominal")]
    design: list[Design]
    goals: list[Goal]
    optimiser: Optimiser = Optimiser()

    @model_validator(mode="after")
    def _check(self) -> TuneSpec:
        for key in self.set:
            field_path(key, f"set.{key}")
        for name, items, most in (
            ("scenarios", self.scenarios, SCENARIOS_MAX),
            ("ensemble", self.ensemble, MEMBERS_MAX),
            ("design", self.design, DESIGN_MAX),
            ("goals", self.goals, GOALS_MAX),
        ):
            if not 1 <= len(items) <= most:
                raise rule(name, f"give 1 to {most}, got {len(items)}")
        _unique("scenarios", [s.name for s in self.scenarios], "label")
        _unique("ensemble", [m.name for m in self.ensemble], "name")
        _unique("design", [d.label for d in self.design], "name")
        _unique("design", [d.field for d in self.design], "field")
        _unique("goals", [g.label for g in self.goals], "name")
        for i, d in enumerate(self.design):
            if d.field in self.set:
                raise rule(f"design[{i}].field", f"{d.field!r} is also in set (a field is either set or designed)")
        names = [m.name for m in self.ensemble]
        for i, g in enumerate(self.goals):
            if isinstance(g.members, list):
                unknown = [n for n in g.members if n not in names]
                if unknown or not g.members:
                    raise rule(f"goals[{i}].members", f"name ensemble members ({', '.join(names)}), got {g.members}")
        soft = [g for g in self.goals if g.kind == "soft"]
        if not 1 <= len(soft) <= 2:
            raise rule("goals", f"give one or two soft goals (minimised), got {len(soft)}")
        return self

    @property
    def soft(self) -> list[Goal]:
        return [g for g in self.goals if g.kind == "soft"]

    @property
    def hard(self) -> list[Goal]:
        return [g for g in self.goals if g.kind == "hard"]


def _unique(where: str, names: list[str], what: str) -> None:
    seen: dict[str, int] = {}
    for i, name in enumerate(names):
        if name in seen:
            raise rule(f"{where}[{i}].{what}", f"{name!r} is already given by {where}[{seen[name]}]")
        seen[name] = i


def load_tune(path: str | Path) -> TuneSpec:
    """Read and validate a tune file (ScenarioError, one line, on any problem)."""
    source = str(path)
    try:
        text = read_input_file(path, "a tune YAML file")
    except InputFileError as exc:
        raise ScenarioError(source, "", str(exc)) from None
    return parse_tune(text, source)


def parse_tune(text: str, source: str) -> TuneSpec:
    """A tune spec from its YAML text."""
    try:
        data = parse_yaml(text, source)
    except ScenarioError as exc:
        message = exc.message.replace("scenario fields", "tune fields").replace("scenario YAML", "YAML")
        raise ScenarioError(source, exc.field, message) from None
    try:
        return TuneSpec.model_validate(data)
    except ValidationError as exc:
        raise_validation(exc, source)


def tunes_dir() -> Path:
    """The shipped tunes: ``gantry_twin/tunes`` in a wheel, ``tunes/`` in a checkout."""
    return scenarios_dir().parent / "tunes"


def tune_file(arg: str) -> Path:
    """A tune file path, or the name of a shipped one (``diarc_paper_paths``) when no such file exists."""
    path = Path(arg)
    named = tunes_dir() / (arg if arg.endswith(".yaml") else f"{arg}.yaml")
    if not path.exists() and "/" not in arg and named.is_file():
        return named
    return path
