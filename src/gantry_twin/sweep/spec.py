"""The sweep file: which scenario, what to set on every point, what to vary, what to keep (docs/sweeps.md).

Validated like a scenario file (pydantic, unknown keys rejected) and
reported the same way: a :class:`~gantry_twin.scenario.ScenarioError`, one
line naming the file, the field path and what is allowed. Whether the
swept values make valid scenarios is checked point by point when the
sweep is planned (:mod:`gantry_twin.sweep.points`), before anything runs.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pydantic import ValidationError, model_validator

from gantry_twin.scenario import (
    ScenarioError,
    parse_yaml,
    read_scenario_file,
    scenarios_dir,
    shipped,
    shipped_scenarios,
)
from gantry_twin.scenario.errors import raise_validation
from gantry_twin.settings import rule
from gantry_twin.sweep.sampling import (
    POINTS_MAX,
    Linspace,
    Logspace,
    Model,
    Num,
    RandomSpec,
    Seed,
    grid_values,
)
from gantry_twin.theta import THETA_NAMES

#: A ``--set`` style field path: names and list indices joined by dots (``disturbance.y.0.value_v``).
FIELD_PATH = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.([A-Za-z_][A-Za-z0-9_]*|[0-9]+))*$")

#: The metrics a row can hold, by group (docs/sweeps.md); ``metrics:`` names groups or columns.
METRIC_GROUPS: dict[str, tuple[str, ...]] = {
    "contour": ("contour_rms_um", "contour_max_um"),
    "axial": ("axial_rms_x_um", "axial_rms_y_um"),
    "command": ("max_abs_u_x_v", "max_abs_u_y_v", "saturated_fraction_x", "saturated_fraction_y"),
    "estimates": tuple(
        f"{what}_{name}" for name in THETA_NAMES for what in ("estimate", "true", "error_pct", "trustworthy")
    ),
    "health": ("alarms",),
}
METRICS = tuple(name for group in METRIC_GROUPS.values() for name in group)


def field_path(value: str, where: str) -> str:
    """``value`` if it is a ``--set`` style field path, else a rule error at ``where`` (a sweep's, a tune's)."""
    if not isinstance(value, str) or not FIELD_PATH.match(value):
        raise rule(
            where, f"must be a scenario field path like payload.mass_kg or disturbance.y.0.value_v, got {value!r}"
        )
    return value


class Axis(Model):
    """One grid axis: a field and its values (``values``, ``linspace`` or ``logspace``)."""

    field: str
    values: list[Any] | None = None
    linspace: Linspace | None = None
    logspace: Logspace | None = None

    @model_validator(mode="after")
    def _check(self) -> Axis:
        field_path(self.field, "field")
        given = [k for k in ("values", "linspace", "logspace") if getattr(self, k) is not None]
        if len(given) != 1:
            raise rule("values", f"give exactly one of values, linspace, logspace (got {', '.join(given) or 'none'})")
        if self.values is not None and not self.values:
            raise rule("values", "must list at least one value, got []")
        return self

    def points(self) -> list[Any]:
        return grid_values(self.values, self.linspace, self.logspace)


class Repeats(Model):
    """Run every point ``count`` times, writing seed, seed + 1, ... into the scenario field ``field``."""

    count: Num
    seed: Seed = 0
    field: str

    @model_validator(mode="after")
    def _check(self) -> Repeats:
        field_path(self.field, "field")
        return self


class SweepSpec(Model):
    """A whole sweep file. Points: the grid of ``axes`` x the ``random`` draws x the ``repeats``."""

    scenario: str
    description: str = ""
    set: dict[str, Any] = {}
    axes: list[Axis] = []
    random: RandomSpec | None = None
    repeats: Repeats | None = None
    metrics: list[str] | None = None
    plots: list[str] | None = None
    keep_runs: bool = False

    @model_validator(mode="after")
    def _check(self) -> SweepSpec:
        for key in self.set:
            field_path(key, f"set.{key}")
        if not (self.axes or self.random or self.repeats):
            raise rule("axes", "a sweep needs axes, random or repeats (none given)")
        seen: dict[str, str] = {}
        for where, field in self.swept():
            if field in seen:
                raise rule(where, f"{field!r} is already swept by {seen[field]}")
            if field in self.set:
                raise rule(where, f"{field!r} is also in set (a field is either set for every point or swept)")
            seen[field] = where
        for i, name in enumerate(self.metrics or ()):
            if name not in METRIC_GROUPS and name not in METRICS:
                raise rule(f"metrics[{i}]", f"unknown metric {name!r}; groups: {', '.join(METRIC_GROUPS)}, or a column")
        kept = self.kept_metrics()
        for i, name in enumerate(self.plots or ()):
            if name not in kept:
                raise rule(f"plots[{i}]", f"{name!r} is not a kept metric; kept: {', '.join(kept)}")
        if self.size() > POINTS_MAX:
            raise rule("axes", f"the sweep holds {self.size()} points; at most {POINTS_MAX}")
        return self

    def swept(self) -> list[tuple[str, str]]:
        """(where in the file, field path) of every swept field, in column order."""
        out = [(f"axes[{i}].field", a.field) for i, a in enumerate(self.axes)]
        if self.random is not None:
            out += [(f"random.fields[{i}].field", f.field) for i, f in enumerate(self.random.fields)]
        if self.repeats is not None:
            out.append(("repeats.field", self.repeats.field))
        return out

    def size(self) -> int:
        n = 1
        for axis in self.axes:
            n *= len(axis.values) if axis.values is not None else (axis.linspace or axis.logspace).num
        n *= self.random.samples if self.random is not None else 1
        return n * (self.repeats.count if self.repeats is not None else 1)

    def kept_metrics(self) -> tuple[str, ...]:
        """The metric columns of the results table (all when ``metrics`` is not given), in METRICS order."""
        if self.metrics is None:
            return METRICS
        named = {m for name in self.metrics for m in METRIC_GROUPS.get(name, (name,))}
        return tuple(m for m in METRICS if m in named)

    def plot_metrics(self) -> tuple[str, ...]:
        """The metrics plotted (``plots``; by default the contour rms, else the first kept metric)."""
        if self.plots is not None:
            return tuple(self.plots)
        kept = self.kept_metrics()
        return ("contour_rms_um",) if "contour_rms_um" in kept else kept[:1]


def load_sweep(path: str | Path) -> SweepSpec:
    """Read and validate a sweep file (ScenarioError, one line, on any problem)."""
    return _validated(lambda: read_scenario_file(path), str(path))


def parse_sweep(text: str, source: str) -> SweepSpec:
    """A sweep from its YAML text (for tests and tools)."""
    return _validated(lambda: parse_yaml(text, source), source)


def _validated(read: Callable[[], dict[str, Any]], source: str) -> SweepSpec:
    try:
        data = read()  # the scenario reader (YAML rules, duplicate keys), its words said of a sweep file
    except ScenarioError as exc:
        raise ScenarioError(source, exc.field, _of_a_sweep(exc.message)) from None
    try:
        return SweepSpec.model_validate(data)
    except ValidationError as exc:
        raise_validation(exc, source)


def _of_a_sweep(message: str) -> str:
    if message.startswith(("empty file", "top level")):
        what = message.split(";")[0].split(" must")[0]
        return f"{what}; expected a YAML mapping with keys: {', '.join(SweepSpec.model_fields)}"
    return message.replace("scenario YAML file", "sweep YAML file")


def scenario_path(spec: SweepSpec, source: str) -> Path:
    """The sweep's scenario: a path relative to the sweep file, or a shipped scenario's name."""
    return named_scenario(spec.scenario, source)


def named_scenario(name: str, source: str, field: str = "scenario") -> Path:
    """A scenario a spec file names (its ``field``): a path relative to the file, or a shipped scenario's name."""
    given = Path(name)
    here = given if given.is_absolute() else Path(source).parent / given
    if here.is_file():
        return here
    if "/" not in name and shipped(name).is_file():
        return shipped(name)
    names = ", ".join(p.stem for p in shipped_scenarios())
    raise ScenarioError(source, field, f"no file {here} and no shipped scenario {name!r}; shipped: {names}")


def sweeps_dir() -> Path:
    """The shipped sweeps: ``gantry_twin/sweeps`` in a wheel, ``sweeps/`` in a checkout (beside the scenarios)."""
    return scenarios_dir().parent / "sweeps"


def sweep_file(arg: str) -> Path:
    """A sweep file path, or the name of a shipped sweep (``payload_0_20kg``) when no such file exists."""
    path = Path(arg)
    named = sweeps_dir() / (arg if arg.endswith(".yaml") else f"{arg}.yaml")
    if not path.exists() and "/" not in arg and named.is_file():
        return named
    return path
