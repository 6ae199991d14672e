"""The calibration file: the targets, the free plant properties with their ranges, the fixed base and the
identification constraint (docs/cli.md, ``calibrate``).

Validated on the package's one pydantic base (:class:`gantry_twin.settings.Model`,
unknown keys rejected) and reported as the scenario files are: a
:class:`~gantry_twin.scenario.ScenarioError`, one line naming the file, the
field and what is allowed. Whether the free fields and the base make valid
scenarios is checked when the calibration is planned
(:mod:`gantry_twin.calibration.fit`), before anything runs or is written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import ValidationError, model_validator

from gantry_twin.inputs import InputFileError, read_input_file
from gantry_twin.scenario import ScenarioError, parse_yaml, scenarios_dir
from gantry_twin.scenario.errors import raise_validation
from gantry_twin.settings import Count, Model, Positive, Range, Real, Vector, fmt, rule
from gantry_twin.theta import AXES

#: Largest optimiser budget (evaluations), and largest number of targets and free properties.
EVALUATIONS_MAX = 10000
TARGETS_MAX = 64
FREE_MAX = 32
#: LuGre's shape, per axis, as a calibration names it under ``plant.friction.<axis>.`` when the identification
#: constraint is given (Fc, Fs and sigma2 then follow from it; sigma0 and sigma1 from the pre-sliding distance
#: Fc / sigma0 and the damping ratio sigma1 / 2 sqrt(sigma0 m)).
SHAPE_FIELDS = ("fs_over_fc", "vs_m_s", "presliding_m", "zeta")
#: The LuGre fields the constraint sets, never given.
CONSTRAINED_FIELDS = ("fc_n", "fs_n", "sigma2_ns_m", "sigma0_n_m", "sigma1_ns_m")

Micrometres = Range(0.0, None, "um", lo_open=True)


class Target(Model):
    """One measured run: a scenario (a shipped name or a path relative to the file) with a controller, and its
    measured contour error rms and / or max over the scenario's metric window, um."""

    scenario: str
    controller: str | None = None
    set: dict[str, Any] = {}
    rms_um: Micrometres | None = None
    max_um: Micrometres | None = None
    weight: Range(0.0, None, lo_open=True) = 1.0
    label: str | None = None

    @model_validator(mode="after")
    def _check(self) -> Target:
        if self.rms_um is None and self.max_um is None:
            raise rule("rms_um", "give rms_um, max_um or both (the measured contour error, um)")
        return self

    def name(self, index: int) -> str:
        return self.label or f"{Path(self.scenario).stem}/{self.controller or 'scenario'}"


class Free(Model):
    """One free property: the scenario field(s) it sets (one value written to each), its range and start."""

    field: str | list[str]
    range: Vector(Real, ("low", "high"))
    start: Real | None = None
    name: str | None = None

    @model_validator(mode="after")
    def _check(self) -> Free:
        low, high = self.range
        if not low < high:
            raise rule("range", f"low must be below high, got [{fmt(low)}, {fmt(high)}]")
        if not self.fields():
            raise rule("field", "name at least one scenario field")
        if self.start is not None and not low <= self.start <= high:
            raise rule("start", f"must be in the range [{fmt(low)}, {fmt(high)}], got {fmt(self.start)}")
        return self

    def fields(self) -> list[str]:
        return [self.field] if isinstance(self.field, str) else list(self.field)

    @property
    def label(self) -> str:
        return self.name or self.fields()[0]

    @property
    def start_value(self) -> float:
        return 0.5 * (self.range[0] + self.range[1]) if self.start is None else float(self.start)


class Identification(Model):
    """What the machine's own identification returned (X, Y; the paper's volt units): B V/(m/s) and Af V set
    Fc and sigma2 of a LuGre plant by the closed form (:func:`gantry_twin.plant.friction.identified_af_b` returns
    them); M V/(m/s^2), if given, is checked against the plant (a calibration does not move masses)."""

    B: Vector(Positive, AXES)  # noqa: N815 -- the paper's symbol
    Af: Vector(Positive, AXES)  # noqa: N815
    M: Vector(Positive, AXES) | None = None  # noqa: N815


class Optimiser(Model):
    """Nelder-Mead in the unit box of the free properties (scipy), from their starts: deterministic."""

    evaluations: Count(1, EVALUATIONS_MAX) = 60
    initial_step: Range(0.01, 0.5) = 0.2
    xatol: Range(0.0, 1.0, lo_open=True) = 0.005
    fatol: Range(0.0, None, lo_open=True) = 1.0e-5


class CalibrationSpec(Model):
    """A whole calibration file."""

    description: str = ""
    base: dict[str, Any] = {}
    targets: list[Target]
    free: list[Free]
    identification: Identification | None = None
    optimiser: Optimiser = Optimiser()

    @model_validator(mode="after")
    def _check(self) -> CalibrationSpec:
        if not self.targets or len(self.targets) > TARGETS_MAX:
            raise rule("targets", f"give 1 to {TARGETS_MAX} targets, got {len(self.targets)}")
        if not self.free or len(self.free) > FREE_MAX:
            raise rule("free", f"give 1 to {FREE_MAX} free properties, got {len(self.free)}")
        seen: dict[str, str] = {}
        labels: dict[str, int] = {}
        for i, free in enumerate(self.free):
            if free.label in labels:
                raise rule(f"free[{i}].name", f"{free.label!r} already names free[{labels[free.label]}]")
            labels[free.label] = i
            for field in free.fields():
                if field in seen:
                    raise rule(f"free[{i}].field", f"{field!r} is already free in {seen[field]}")
                if field in self.base:
                    raise rule(f"free[{i}].field", f"{field!r} is also in base (a field is either fixed or free)")
                seen[field] = f"free[{i}]"
        return self


def friction_field(field: str) -> tuple[str, str] | None:
    """(axis, name) of a ``plant.friction.<axis>.<name>`` field path, else None."""
    parts = field.split(".")
    if len(parts) == 4 and parts[:2] == ["plant", "friction"] and parts[2] in AXES:
        return parts[2], parts[3]
    return None


def load_calibration(path: str | Path) -> CalibrationSpec:
    """Read and validate a calibration file (ScenarioError, one line, on any problem)."""
    source = str(path)
    try:
        text = read_input_file(path, "a calibration YAML file")
    except InputFileError as exc:
        raise ScenarioError(source, "", str(exc)) from None
    try:
        data = parse_yaml(text, source)
    except ScenarioError as exc:
        message = exc.message.replace("scenario fields", "calibration fields").replace("scenario YAML", "YAML")
        raise ScenarioError(source, exc.field, message) from None
    try:
        return CalibrationSpec.model_validate(data)
    except ValidationError as exc:
        raise_validation(exc, source)


def calibrations_dir() -> Path:
    """The shipped calibrations: ``gantry_twin/calibrations`` in a wheel, ``calibrations/`` in a checkout."""
    return scenarios_dir().parent / "calibrations"


def calibration_file(arg: str) -> Path:
    """A calibration file path, or the name of a shipped one (``paper_circle_set1``) when no such file exists."""
    path = Path(arg)
    named = calibrations_dir() / (arg if arg.endswith(".yaml") else f"{arg}.yaml")
    if not path.exists() and "/" not in arg and named.is_file():
        return named
    return path
