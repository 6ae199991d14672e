"""A tune's plan: every run a trial makes (its cases), checked on the driver before anything runs or is written.

A case is one scenario on one ensemble member (and, for a goal with its own
``set``, with that goal's fields set): the scenario file, then the tune's
``set``, the scenario's, the member's, the goal's and last the design's
values, applied as ``gantry-twin run --set`` applies them and validated and
built as ``gantry-twin run`` builds them (:mod:`gantry_twin.sweep.points`).
The first cases are the nominal member's (``ensemble[0]``) on every scenario,
a goal's own runs on it included: a trial runs them first and stops when a
hard goal already fails there.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gantry_twin.run import package_version
from gantry_twin.scenario import ScenarioError, apply_overrides, build, read_scenario_file, validate_data
from gantry_twin.sweep.points import override
from gantry_twin.sweep.spec import named_scenario
from gantry_twin.tune.goals import Check
from gantry_twin.tune.spec import Goal, TuneSpec


@dataclass(frozen=True)
class Case:
    """One run of every trial: scenario ``scenario`` on member ``member``, with goal ``goal``'s fields if set."""

    label: str
    scenario: int
    member: int
    goal: int | None
    path: Path
    overrides: tuple[str, ...]


@dataclass(frozen=True)
class TunePlan:
    """Every case, checked; the cases each goal is judged on; the baseline design (the scenario's own values of
    the design fields, None where it has none); the scenario files read once."""

    spec: TuneSpec
    source: str
    cases: tuple[Case, ...]
    nominal: int
    goal_cases: tuple[tuple[int, ...], ...]
    baseline_design: dict[str, float | None]
    files: dict[str, dict[str, Any]]
    version: str

    def resolved(self, values: dict[str, float] | None) -> list[dict[str, Any]]:
        """The resolved scenario of every case with the design ``values`` (by design label; None: the baseline)."""
        return [self.resolve_case(c, values)[0] for c in self.cases]

    def resolve_case(self, case: Case, values: dict[str, float] | None) -> tuple[dict[str, Any], dict[str, Any]]:
        """(resolved scenario, the data before validation) of one case with the design ``values``."""
        design = [] if values is None else [override(d.field, values[d.label]) for d in self.spec.design]
        path = str(case.path)
        data = apply_overrides(self.files[path], [*case.overrides, *design], path)
        scenario = validate_data(data, path, default_name=case.path.stem)
        return scenario.resolved(), data

    def checks(self, baseline: list[dict[str, float] | None] | None) -> list[Check]:
        """The goals as a trial judges them; a relative goal's limit times the baseline's worst over its cases."""
        out = []
        for goal, cases in zip(self.spec.goals, self.goal_cases, strict=True):
            limit = goal.limit
            if goal.relative:
                if baseline is None:
                    raise ValueError(f"goal {goal.label}: a relative limit needs the baseline's runs")
                worst = max(float(baseline[i][goal.metric]) for i in cases if baseline[i] is not None)
                limit = goal.limit * worst
            out.append(Check(goal.label, goal.metric, goal.kind, float(limit), cases))
        return out


def _cases(spec: TuneSpec, paths: list[Path]) -> tuple[list[Case], int, list[tuple[int, ...]]]:
    def make(s: int, m: int, g: int | None) -> Case:
        ref, member = spec.scenarios[s], spec.ensemble[m]
        sets = [spec.set, ref.set, member.set, spec.goals[g].set if g is not None else {}]
        overrides = tuple(override(k, v) for part in sets for k, v in part.items())
        label = f"{ref.name}/{member.name}" + (f"/{spec.goals[g].label}" if g is not None else "")
        return Case(label, s, m, g, paths[s], overrides)

    scenarios = range(len(spec.scenarios))
    cases = [make(s, m, None) for m in range(len(spec.ensemble)) for s in scenarios]
    for g, goal in enumerate(spec.goals):
        if goal.set:
            cases += [make(s, m, g) for m in _members(spec, goal) for s in scenarios]
    cases.sort(key=lambda c: c.member != 0)  # the nominal member's runs first (stable: scenario 0 first of all)
    nominal = sum(c.member == 0 for c in cases)
    goal_cases = []
    for g, goal in enumerate(spec.goals):
        want, members = (g if goal.set else None), _members(spec, goal)
        goal_cases.append(tuple(i for i, c in enumerate(cases) if c.goal == want and c.member in members))
    return cases, nominal, goal_cases


def _members(spec: TuneSpec, goal: Goal) -> list[int]:
    """The ensemble members a goal is judged on (indices)."""
    if goal.members == "all":
        return list(range(len(spec.ensemble)))
    if goal.members == "nominal":
        return [0]
    names = [m.name for m in spec.ensemble]
    return [names.index(n) for n in goal.members]


def _at(data: Any, field: str) -> Any:
    for part in field.split("."):
        if isinstance(data, list) and part.isdigit() and int(part) < len(data):
            data = data[int(part)]
        elif isinstance(data, dict) and part in data:
            data = data[part]
        else:
            return None
    return data


def plan_tune(spec: TuneSpec, source: str) -> TunePlan:
    """Every case at the baseline and at the design's low and high corners, loaded, validated and built as
    ``gantry-twin run`` would: a ScenarioError names the case and the field."""
    paths = [named_scenario(ref.scenario, source, f"scenarios[{i}].scenario") for i, ref in enumerate(spec.scenarios)]
    files = {str(p): read_scenario_file(p) for p in paths}
    cases, nominal, goal_cases = _cases(spec, paths)
    plan = TunePlan(spec, source, tuple(cases), nominal, tuple(goal_cases), {}, files, package_version())
    corners: list[tuple[str, dict[str, float] | None]] = [("the baseline", None)]
    for end in ("low", "high"):
        corners.append((f"every design variable at its {end}", {d.label: getattr(d, end) for d in spec.design}))
    for i, d in enumerate(spec.design):  # each field on its own first: an unknown field is named as itself
        one = {e.label: (e.low if e is not d else d.high) for e in spec.design}
        corners.insert(1 + i, (f"design[{i}] ({d.field})", one))
    baseline: dict[str, float | None] = {}
    for what, values in corners:
        for case in cases:
            try:
                resolved, data = plan.resolve_case(case, values)
                if values is None or case is cases[0]:  # the design's corners: validated everywhere, built once
                    build(validate_data(resolved, str(case.path)), str(case.path))
            except ScenarioError as exc:
                detail = f"{exc.field}: {exc.message}" if exc.field else exc.message
                raise ScenarioError(source, f"{case.label} with {what}", detail) from None
            if values is None and case is cases[0]:
                for d in spec.design:
                    found = _at(data, d.field)
                    ok = isinstance(found, int | float) and not isinstance(found, bool)
                    baseline[d.label] = float(found) if ok else None
    return TunePlan(spec, source, tuple(cases), nominal, tuple(goal_cases), baseline, files, package_version())
