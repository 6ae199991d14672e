"""Scenario files: one typed schema, files that say only what differs, --set overrides.

A scenario is a YAML mapping validated into :class:`Scenario` (pydantic v2,
unknown keys rejected). Every field has a default from the control spec, so
``{}`` is a valid scenario: DIARC on the paper's circle, no load, no
disturbance, quantised sensing, 30 s. :func:`load_scenario` reads a file,
applies ``--set key.path=value`` overrides and checks the cross-field rules
(windows inside the duration); :func:`build` turns a scenario into the
objects :func:`gantry_twin.simulate.simulate` takes, and checks what needs the
compiled model (the contour inside the travel) and the controller's options.

Every problem is raised as :class:`ScenarioError`, whose message is one line
naming the file, the field path and what is allowed. docs/scenarios.md is the
reference of every field.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
import yaml
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    model_validator,
)
from pydantic_core import PydanticCustomError

from gantry_twin import changes as ch
from gantry_twin.controllers import (
    DARC,
    DIARC,
    DRC,
    PD,
    RECOMMENDED_ESTIMATOR,
    ArcGains,
    Controller,
    EstimatorSettings,
    available,
    create,
)
from gantry_twin.controllers.base import factory_for
from gantry_twin.estimation import LeastSquaresSettings
from gantry_twin.paths import Ellipse, TimingLaw
from gantry_twin.plant import AXES, PAYLOAD_MAX_KG, PAYLOAD_OFFSET_MAX_M, Payload, Plant
from gantry_twin.sensing import ENCODER_RESOLUTION_M, SensingConfig
from gantry_twin.simulate import Disturbance

#: Version of the scenario schema (bumped when a field changes meaning).
SCENARIO_SCHEMA_VERSION = 1
#: Longest run accepted, s (30 s is the paper's; an hour is 18 M samples).
DURATION_MAX_S = 3600.0
#: Largest disturbance amplitude of one event, volts (the DAC range is +-10 V).
DISTURBANCE_MAX_V = 10.0
#: Clearance kept between a contour and the end of travel, metres.
TRAVEL_MARGIN_M = 0.005


class ScenarioError(ValueError):
    """A scenario that cannot run; ``str()`` is one line: file, field, what is allowed."""

    def __init__(self, source: str, field: str, message: str) -> None:
        self.source = source
        self.field = field
        self.message = message
        where = f"{source}: {field}: " if field else f"{source}: "
        super().__init__(where + message)


# ---------------------------------------------------------------------------
# Field types: numbers that reject booleans and say their range when wrong.


def _not_bool(value: Any) -> Any:
    if isinstance(value, bool):
        raise PydanticCustomError("number_type", "must be a number, not a boolean")
    return value


def _fmt(x: float) -> str:
    return f"{x:g}"


def _range(lo: float | None, hi: float | None, unit: str, lo_open: bool = False) -> Any:
    """A float in [lo, hi] (or (lo, hi] with lo_open) whose error states the range."""
    left = "(" if lo_open else "["
    text = f"{left}{_fmt(lo) if lo is not None else '-inf'}, {_fmt(hi) if hi is not None else 'inf'}] {unit}".rstrip()

    def check(value: float) -> float:
        bad = not math.isfinite(value)
        bad |= lo is not None and (value <= lo if lo_open else value < lo)
        bad |= hi is not None and value > hi
        if bad:
            raise PydanticCustomError("range", "must be in {allowed}, got {value}", {"allowed": text, "value": value})
        return value

    return Annotated[float, BeforeValidator(_not_bool), AfterValidator(check)]


Seconds = _range(0.0, None, "s")
Volts = _range(-DISTURBANCE_MAX_V, DISTURBANCE_MAX_V, "V")
Positive = _range(0.0, None, "", lo_open=True)
NonNegative = _range(0.0, None, "")
Real = _range(None, None, "")


class _Model(BaseModel):
    """Frozen, unknown keys rejected with the list of allowed keys."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        if isinstance(data, dict):
            for key in data:
                if key not in cls.model_fields:
                    raise PydanticCustomError(
                        "unknown_key",
                        "unknown key '{key}'; allowed: {allowed}",
                        {"key": key, "allowed": ", ".join(cls.model_fields)},
                    )
        return data


# ---------------------------------------------------------------------------
# The schema.


class TimingSpec(_Model):
    """phi(t): constant rate after an optional smooth start (control-spec section 3)."""

    rate_rad_s: _range(0.0, 20.0, "rad/s", lo_open=True) | None = None  # type: ignore[valid-type]
    start: Literal["on_path", "rest"] = "on_path"
    ramp_s: _range(0.0, 60.0, "s", lo_open=True) = 0.5  # type: ignore[valid-type]


Point2 = tuple[Real, Real]  # type: ignore[valid-type]


class CircleSpec(_Model):
    """The paper's circle (5.1): radius 0.2 m at 2 rad/s (0.4 m/s)."""

    type: Literal["circle"] = "circle"
    radius_m: _range(0.0, 1.0, "m", lo_open=True) = 0.2  # type: ignore[valid-type]
    centre_m: Point2 = (0.0, 0.0)
    timing: TimingSpec = TimingSpec()

    default_rate_rad_s: ClassVar[float] = 2.0

    def path(self) -> Ellipse:
        return Ellipse(self.radius_m, self.radius_m, tuple(self.centre_m))


class EllipseSpec(_Model):
    """p(phi) = centre + [a sin phi, -b cos phi]; the paper's (5.2) at 3 rad/s."""

    type: Literal["ellipse"] = "ellipse"
    semi_x_m: _range(0.0, 1.0, "m", lo_open=True) = 0.2  # type: ignore[valid-type]
    semi_y_m: _range(0.0, 1.0, "m", lo_open=True) = 0.1  # type: ignore[valid-type]
    centre_m: Point2 = (0.0, 0.1)
    timing: TimingSpec = TimingSpec()

    default_rate_rad_s: ClassVar[float] = 3.0

    def path(self) -> Ellipse:
        return Ellipse(self.semi_x_m, self.semi_y_m, tuple(self.centre_m))


ContourSpec = Annotated[CircleSpec | EllipseSpec, Field(discriminator="type")]


class PayloadSpec(_Model):
    """A payload body on the X carriage (0 kg = none; Set 2: 5 kg)."""

    mass_kg: _range(0.0, PAYLOAD_MAX_KG, "kg") = 0.0  # type: ignore[valid-type]
    offset_m: tuple[
        _range(-PAYLOAD_OFFSET_MAX_M[0], PAYLOAD_OFFSET_MAX_M[0], "m"),  # type: ignore[valid-type]
        _range(-PAYLOAD_OFFSET_MAX_M[1], PAYLOAD_OFFSET_MAX_M[1], "m"),  # type: ignore[valid-type]
        _range(-PAYLOAD_OFFSET_MAX_M[2], PAYLOAD_OFFSET_MAX_M[2], "m"),  # type: ignore[valid-type]
    ] = (0.0, 0.0, 0.05)


class _Event(_Model):
    start_s: Seconds = 0.0  # type: ignore[valid-type]
    end_s: Seconds | None = None  # type: ignore[valid-type]

    @model_validator(mode="after")
    def _ordered(self) -> _Event:
        if self.end_s is not None and self.end_s <= self.start_s:
            raise PydanticCustomError(
                "order", "end_s must be after start_s = {start}, got {end}", {"start": self.start_s, "end": self.end_s}
            )
        return self

    def _active(self, t: np.ndarray) -> np.ndarray:
        end = math.inf if self.end_s is None else self.end_s
        return (t >= self.start_s) & (t < end)


class StepEvent(_Event):
    """value_v on [start_s, end_s) (end_s omitted: to the end of the run)."""

    type: Literal["step"] = "step"
    value_v: Volts  # type: ignore[valid-type]
    start_s: Seconds = 0.0  # type: ignore[valid-type]
    end_s: Seconds | None = None  # type: ignore[valid-type]

    def volts(self, t: np.ndarray) -> np.ndarray:
        return np.where(self._active(t), self.value_v, 0.0)


class RampEvent(_Event):
    """Linear from from_v at start_s to to_v at end_s, zero outside [start_s, end_s)."""

    type: Literal["ramp"] = "ramp"
    from_v: Volts = 0.0  # type: ignore[valid-type]
    to_v: Volts  # type: ignore[valid-type]
    start_s: Seconds = 0.0  # type: ignore[valid-type]
    end_s: Seconds  # type: ignore[valid-type]

    def volts(self, t: np.ndarray) -> np.ndarray:
        frac = (t - self.start_s) / (self.end_s - self.start_s)
        return np.where(self._active(t), self.from_v + (self.to_v - self.from_v) * frac, 0.0)


class SineEvent(_Event):
    """amplitude_v sin(2 pi frequency_hz t + phase_rad) on [start_s, end_s), t the run time."""

    type: Literal["sine"] = "sine"
    amplitude_v: Volts  # type: ignore[valid-type]
    frequency_hz: _range(0.0, 2500.0, "Hz", lo_open=True)  # type: ignore[valid-type]
    phase_rad: Real = 0.0  # type: ignore[valid-type]
    start_s: Seconds = 0.0  # type: ignore[valid-type]
    end_s: Seconds | None = None  # type: ignore[valid-type]

    def volts(self, t: np.ndarray) -> np.ndarray:
        wave = self.amplitude_v * np.sin(2.0 * np.pi * self.frequency_hz * t + self.phase_rad)
        return np.where(self._active(t), wave, 0.0)


EventSpec = Annotated[StepEvent | RampEvent | SineEvent, Field(discriminator="type")]


class DisturbanceSpec(_Model):
    """Input disturbance per axis (volts, summed over events), unseen by the controller."""

    x: list[EventSpec] = []
    y: list[EventSpec] = []

    def function(self) -> Disturbance:
        """t (N,) s -> (N, 2) volts, for ``simulate(disturbance=...)``."""
        per_axis = (tuple(self.x), tuple(self.y))

        def volts(t_s: np.ndarray) -> np.ndarray:
            t = np.asarray(t_s, dtype=float)
            out = np.zeros((t.size, 2))
            for axis, events in enumerate(per_axis):
                for event in events:
                    out[:, axis] += event.volts(t)
            return out

        return volts

    @property
    def empty(self) -> bool:
        return not (self.x or self.y)


class ControllerSpec(_Model):
    """A controller by registry name and the keyword options of its factory."""

    name: str = "diarc"
    options: dict[str, Any] = {}

    @model_validator(mode="after")
    def _known_name(self) -> ControllerSpec:
        names = available()
        if self.name not in names:
            raise PydanticCustomError(
                "unknown_controller",
                "unknown controller '{name}'; available: {names}",
                {"name": self.name, "names": ", ".join(names)},
            )
        return self


class SensingSpec(_Model):
    """Encoder quantisation and velocity by backward difference (control-spec section 2)."""

    quantize: bool = True
    resolution_m: _range(0.0, 1e-3, "m", lo_open=True) = ENCODER_RESOLUTION_M  # type: ignore[valid-type]
    velocity_by_difference: bool = True

    def config(self) -> SensingConfig:
        return SensingConfig(self.quantize, self.resolution_m, self.velocity_by_difference)


class OutputsSpec(_Model):
    """Where and what ``gantry-twin run`` writes."""

    dir: str | None = None
    trace: bool = True
    trace_stride: Annotated[int, Field(ge=1, le=100000)] = 1


Window = tuple[Seconds, Seconds]  # type: ignore[valid-type]
Axis = Literal["x", "y"]
TimeS = _range(0.0, ch.TIME_MAX_S, "s")
Viscous = _range(*ch.VISCOUS_RANGE_V_S_M, "V/(m/s)")
Coulomb = _range(*ch.COULOMB_RANGE_V, "V")


class FrictionDriftSpec(_Model):
    """B and/or Af of one axis linear from the *_from value (default: the model's) at start_s to *_to at end_s."""

    axis: Axis
    start_s: TimeS  # type: ignore[valid-type]
    end_s: TimeS  # type: ignore[valid-type]
    viscous_to_v_s_m: Viscous | None = None  # type: ignore[valid-type]
    viscous_from_v_s_m: Viscous | None = None  # type: ignore[valid-type]
    coulomb_to_v: Coulomb | None = None  # type: ignore[valid-type]
    coulomb_from_v: Coulomb | None = None  # type: ignore[valid-type]


class PayloadChangeSpec(_Model):
    """From time_s on the payload on the X carriage weighs mass_kg (0: dropped)."""

    time_s: TimeS  # type: ignore[valid-type]
    mass_kg: _range(0.0, PAYLOAD_MAX_KG, "kg")  # type: ignore[valid-type]


class CoggingSpec(_Model):
    """amplitude_v sin(2 pi q / pitch_m + phase_rad) volts on one axis, q the true position."""

    axis: Axis
    amplitude_v: _range(*ch.COGGING_AMPLITUDE_RANGE_V, "V")  # type: ignore[valid-type]
    pitch_m: _range(*ch.COGGING_PITCH_RANGE_M, "m")  # type: ignore[valid-type]
    phase_rad: _range(-2.0 * math.pi, 2.0 * math.pi, "rad") = 0.0  # type: ignore[valid-type]


class EncoderGlitchSpec(_Model):
    """spike: one reading of axis off by offset_m; hold: both readings repeated for samples samples."""

    kind: Literal["spike", "hold"]
    time_s: TimeS  # type: ignore[valid-type]
    axis: Axis = "x"
    offset_m: _range(-ch.SPIKE_OFFSET_MAX_M, ch.SPIKE_OFFSET_MAX_M, "m") = 50.0e-6  # type: ignore[valid-type]
    samples: Annotated[int, Field(ge=ch.HOLD_SAMPLES_RANGE[0], le=ch.HOLD_SAMPLES_RANGE[1])] = 1


class VelocityNoiseSpec(_Model):
    """Extra Gaussian noise (std per axis X, Y, m/s) on the measured velocity over [start_s, end_s)."""

    std_m_s: tuple[_range(*ch.VELOCITY_NOISE_STD_RANGE_M_S, "m/s"),  # type: ignore[valid-type]
                   _range(*ch.VELOCITY_NOISE_STD_RANGE_M_S, "m/s")]  # type: ignore[valid-type]
    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0
    start_s: TimeS = 0.0  # type: ignore[valid-type]
    end_s: TimeS = ch.TIME_MAX_S  # type: ignore[valid-type]


class ChangesSpec(_Model):
    """Faults applied to the plant and the sensor during the run (gantry_twin.changes), unseen by the controller."""

    friction_drift: list[FrictionDriftSpec] = []
    payload_change: list[PayloadChangeSpec] = []
    cogging: list[CoggingSpec] = []
    encoder_glitch: list[EncoderGlitchSpec] = []
    velocity_noise: VelocityNoiseSpec | None = None

    def plant_changes(self) -> ch.PlantChanges:
        """The validated PlantChanges (ValueError "field: message" on a cross-field problem)."""
        def items(specs: Sequence[_Model], kind: type) -> tuple:
            out = []
            for i, spec in enumerate(specs):
                try:
                    out.append(kind(**spec.model_dump()))
                except ValueError as exc:
                    field, _, message = str(exc).partition(": ")
                    raise ValueError(f"{field.split('.')[0]}[{i}].{field.partition('.')[2]}: {message}") from None
            return tuple(out)

        noise = None
        if self.velocity_noise is not None:
            given = self.velocity_noise.model_dump()
            noise = ch.VelocityNoise(**{**given, "std_m_s": tuple(given["std_m_s"])})
        return ch.PlantChanges(items(self.friction_drift, ch.FrictionDrift),
                               items(self.payload_change, ch.PayloadChange),
                               items(self.cogging, ch.CoggingRipple), items(self.encoder_glitch, ch.EncoderGlitch),
                               noise)  # fmt: skip

    @property
    def empty(self) -> bool:
        return not (self.friction_drift or self.payload_change or self.cogging or self.encoder_glitch
                    or self.velocity_noise)


class MonitorSpec(_Model):
    """The excitation and health monitor (gantry_twin.monitor, docs/health.md)."""

    enable: bool = False
    baseline_window_s: Window = (20.0, 30.0)
    baseline_summary: str | None = None
    judge_from_s: Seconds | None = None  # type: ignore[valid-type]
    tolerance_pct: _range(0.0, 100.0, "%", lo_open=True) = 10.0  # type: ignore[valid-type]
    tolerance_dn_v: _range(0.0, DISTURBANCE_MAX_V, "V", lo_open=True) = 0.1  # type: ignore[valid-type]
    decision_interval_s: _range(0.0, 100.0, "s", lo_open=True) = 0.1  # type: ignore[valid-type]
    excitation_window_s: _range(0.01, 600.0, "s") = 2.0  # type: ignore[valid-type]
    min_parameter_v: _range(0.0, 10.0, "V") = 0.01  # type: ignore[valid-type]
    filter_hz: tuple[_range(0.0, 2000.0, "Hz", lo_open=True), _range(0.0, 2000.0, "Hz", lo_open=True)] | None = None  # type: ignore

    @model_validator(mode="after")
    def _ordered(self) -> MonitorSpec:
        a, b = self.baseline_window_s
        if b <= a:
            raise PydanticCustomError("order", "end must be after start, got [{a}, {b}] s", {"a": a, "b": b})
        return self


class Scenario(_Model):
    """A whole run. Every field has a default; see docs/scenarios.md."""

    name: str | None = None
    description: str = ""
    contour: ContourSpec = CircleSpec()
    payload: PayloadSpec = PayloadSpec()
    disturbance: DisturbanceSpec = DisturbanceSpec()
    controller: ControllerSpec = ControllerSpec()
    sensing: SensingSpec = SensingSpec()
    duration_s: _range(0.0, DURATION_MAX_S, "s", lo_open=True) = 30.0  # type: ignore[valid-type]
    window_s: Window | None = None
    estimates_window_s: Window | None = None
    changes: ChangesSpec = ChangesSpec()
    monitor: MonitorSpec = MonitorSpec()

    outputs: OutputsSpec = OutputsSpec()

    @model_validator(mode="before")
    @classmethod
    def _circle_by_default(cls, data: Any) -> Any:
        """A contour mapping without ``type`` is a circle (the default contour)."""
        if isinstance(data, dict) and isinstance(data.get("contour"), dict) and "type" not in data["contour"]:
            data = {**data, "contour": {"type": "circle", **data["contour"]}}
        return data

    # -- derived quantities -------------------------------------------------
    @property
    def rate_rad_s(self) -> float:
        rate = self.contour.timing.rate_rad_s
        return self.contour.default_rate_rad_s if rate is None else rate

    @property
    def period_s(self) -> float:
        """T = 2 pi / rate: one lap of the contour at full speed."""
        return 2.0 * math.pi / self.rate_rad_s

    def timing_law(self) -> TimingLaw:
        t = self.contour.timing
        return TimingLaw(self.rate_rad_s, t.start, t.ramp_s)

    @property
    def metric_window_s(self) -> tuple[float, float]:
        """window_s, or the second period [t0 + T, t0 + 2T] (t0: end of the start ramp)."""
        if self.window_s is not None:
            return (float(self.window_s[0]), float(self.window_s[1]))
        t0 = self.timing_law().settled_s
        return (t0 + self.period_s, t0 + 2.0 * self.period_s)

    @property
    def estimate_window_s(self) -> tuple[float, float]:
        """estimates_window_s, or the last period [duration - T, duration]."""
        if self.estimates_window_s is not None:
            return (float(self.estimates_window_s[0]), float(self.estimates_window_s[1]))
        return (self.duration_s - self.period_s, self.duration_s)

    def resolved(self) -> dict[str, Any]:
        """Every field with its value (defaults and windows filled in), JSON-compatible."""
        data = self.model_dump(mode="json")
        data["contour"]["timing"]["rate_rad_s"] = self.rate_rad_s
        data["window_s"] = list(self.metric_window_s)
        data["estimates_window_s"] = list(self.estimate_window_s)
        return data


# ---------------------------------------------------------------------------
# Controller options: typed for the built-ins, passed through for plug-ins.


Pair = tuple[Positive, Positive]  # type: ignore[valid-type]
PairNonNeg = tuple[NonNegative, NonNegative]  # type: ignore[valid-type]
Theta = tuple[Real, Real, Real, Real, Real, Real, Real, Real]  # type: ignore[valid-type]
ThetaNonNeg = tuple[  # type: ignore[valid-type]
    NonNegative, NonNegative, NonNegative, NonNegative, NonNegative, NonNegative, NonNegative, NonNegative
]
ThetaPositive = tuple[Positive, Positive, Positive, Positive, Positive, Positive, Positive, Positive]  # type: ignore


class GainsSpec(_Model):
    """Overrides of :class:`ArcGains` (omitted fields keep the paper's values)."""

    lambda_1_s: Pair | None = None
    ks_v_s_m: Pair | None = None
    friction_slope_s_m: Positive | None = None  # type: ignore[valid-type]
    theta0: Theta | None = None
    theta_min: Theta | None = None
    theta_max: Theta | None = None

    def gains(self) -> ArcGains:
        given = {k: v for k, v in self.model_dump().items() if v is not None}
        gains = ArcGains(**{k: tuple(v) if isinstance(v, list | tuple) else v for k, v in given.items()})
        lo, hi, th = gains.lower, gains.upper, np.asarray(gains.theta0)
        if np.any(lo > hi) or np.any(th < lo) or np.any(th > hi):
            raise PydanticCustomError("theta_order", "need theta_min <= theta0 <= theta_max element-wise", {})
        return gains

    @model_validator(mode="after")
    def _bounds(self) -> GainsSpec:
        self.gains()
        return self


class LeastSquaresSpec(_Model):
    nu: NonNegative | None = None  # type: ignore[valid-type]
    kappa: NonNegative | None = None  # type: ignore[valid-type]
    rho_max: Positive | None = None  # type: ignore[valid-type]
    gamma0_diag: ThetaPositive | None = None


class EstimatorSpec(_Model):
    """Explicit DIARC estimator settings; omitted fields keep the paper's."""

    filter_hz: tuple[_range(0.0, 2500.0, "Hz", lo_open=True), _range(0.0, 2500.0, "Hz", lo_open=True)] | None = None  # type: ignore
    filter_zeta: _range(0.0, 5.0, "", lo_open=True) | None = None  # type: ignore[valid-type]
    least_squares: LeastSquaresSpec | None = None
    gamma_d: PairNonNeg | None = None
    dc_max_v: PairNonNeg | None = None
    settle_s: NonNegative | None = None  # type: ignore[valid-type]

    def settings(self) -> EstimatorSettings:
        base = EstimatorSettings()
        given = {k: v for k, v in self.model_dump(exclude={"least_squares"}).items() if v is not None}
        ls = base.least_squares
        if self.least_squares is not None:
            ls_given = {k: v for k, v in self.least_squares.model_dump().items() if v is not None}
            ls = LeastSquaresSettings(**{**ls.__dict__, **{k: _tuple(v) for k, v in ls_given.items()}})
        fields = {**base.__dict__, **{k: _tuple(v) for k, v in given.items()}, "least_squares": ls}
        return EstimatorSettings(**fields)


def _tuple(value: Any) -> Any:
    return tuple(value) if isinstance(value, list | tuple) else value


class DrcOptions(_Model):
    gains: GainsSpec = GainsSpec()
    theta: Theta | None = None

    def kwargs(self) -> dict[str, Any]:
        return {"gains": self.gains.gains(), "theta": None if self.theta is None else tuple(self.theta)}


class DarcOptions(_Model):
    gains: GainsSpec = GainsSpec()
    gamma: ThetaNonNeg | None = None

    def kwargs(self) -> dict[str, Any]:
        out: dict[str, Any] = {"gains": self.gains.gains()}
        if self.gamma is not None:
            out["gamma"] = tuple(self.gamma)
        return out


class DiarcOptions(_Model):
    gains: GainsSpec = GainsSpec()
    estimator: Literal["paper", "recommended"] | EstimatorSpec = "paper"

    def kwargs(self) -> dict[str, Any]:
        if self.estimator == "paper":
            estimator = EstimatorSettings()
        elif self.estimator == "recommended":
            estimator = RECOMMENDED_ESTIMATOR
        else:
            estimator = self.estimator.settings()
        return {"gains": self.gains.gains(), "estimator": estimator}


class PdOptions(_Model):
    kp_v_m: PairNonNeg | None = None
    kd_v_s_m: PairNonNeg | None = None
    kv_v_s_m: PairNonNeg | None = None
    ka_v_s2_m: PairNonNeg | None = None

    def kwargs(self) -> dict[str, Any]:
        return {k: tuple(v) for k, v in self.model_dump().items() if v is not None}


#: Typed options of the built-in controllers, keyed by their factory.
BUILTIN_OPTIONS: dict[Any, type[_Model]] = {DRC: DrcOptions, DARC: DarcOptions, DIARC: DiarcOptions, PD: PdOptions}


# ---------------------------------------------------------------------------
# Loading: YAML -> dict -> overrides -> Scenario -> cross-field checks.


class _UniqueKeyLoader(yaml.SafeLoader):
    """safe_load that rejects a key given twice in one mapping."""


def _mapping_unique(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            mark = key_node.start_mark
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r} at line {mark.line + 1}, column {mark.column + 1}", mark
            )
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping_unique)


def parse_yaml(text: str, source: str) -> dict[str, Any]:
    """The top-level mapping of a scenario file (empty mapping not allowed)."""
    try:
        data = yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 -- a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ScenarioError(source, "", f"{where}YAML syntax error: {problem}") from None
    if data is None:
        raise ScenarioError(
            source, "", "empty file; expected a YAML mapping of scenario fields (write {} for all defaults)"
        )
    if not isinstance(data, dict):
        raise ScenarioError(
            source,
            "",
            f"top level must be a mapping of fields ({', '.join(Scenario.model_fields)}), got {type(data).__name__}",
        )
    return data


def read_scenario_file(path: str | Path) -> dict[str, Any]:
    """Read and parse a scenario file; missing or unreadable files are ScenarioErrors."""
    source = str(path)
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ScenarioError(source, "", "no such file; give a scenario YAML file") from None
    except IsADirectoryError:
        raise ScenarioError(source, "", "is a directory; give a scenario YAML file") from None
    except UnicodeDecodeError:
        raise ScenarioError(source, "", "not UTF-8 text; give a scenario YAML file") from None
    except OSError as exc:
        raise ScenarioError(source, "", f"cannot read ({exc.strerror})") from None
    return parse_yaml(text, source)


def apply_overrides(data: dict[str, Any], overrides: Iterable[str], source: str) -> dict[str, Any]:
    """Apply ``key.path=value`` overrides (value parsed as YAML) to a copy of data."""
    import copy

    out = copy.deepcopy(data)
    for item in overrides:
        key, sep, text = item.partition("=")
        parts = key.strip().split(".")
        if not sep or not key.strip() or any(not p for p in parts):
            raise ScenarioError(source, "--set", f"{item!r}: expected key.path=value, e.g. payload.mass_kg=5")
        try:
            value = yaml.safe_load(text) if text.strip() else None
        except yaml.YAMLError as exc:
            raise ScenarioError(source, f"--set {key}", f"value {text!r} is not valid YAML ({exc.problem})") from None
        node: Any = out
        for depth, part in enumerate(parts[:-1]):
            here = ".".join(parts[: depth + 1])
            if isinstance(node, list):
                node = _list_item(node, part, source, here)
                continue
            if not isinstance(node, dict):
                raise ScenarioError(source, f"--set {key}", f"{here.rpartition('.')[0]} is not a mapping")
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            node = child
        last = parts[-1]
        if isinstance(node, list):
            index = _list_index(node, last, source, key)
            node[index] = value
        elif isinstance(node, dict):
            node[last] = value
        else:
            parent = ".".join(parts[:-1])
            raise ScenarioError(source, f"--set {key}", f"{parent} is a {type(node).__name__}, not a mapping")
    return out


def _list_index(node: list[Any], part: str, source: str, key: str) -> int:
    if not part.isdigit() or int(part) >= len(node):
        raise ScenarioError(source, f"--set {key}", f"index {part!r} not in 0..{len(node) - 1}")
    return int(part)


def _list_item(node: list[Any], part: str, source: str, key: str) -> Any:
    return node[_list_index(node, part, source, key)]


_TAGS = {"circle", "ellipse", "step", "ramp", "sine", "function-after[_bounds(), GainsSpec]"}


def _loc_text(loc: Sequence[Any]) -> str:
    text = ""
    for i, part in enumerate(loc):
        if isinstance(part, int):
            text += f"[{part}]"
            continue
        previous = loc[i - 1] if i else None
        if part in _TAGS and (previous == "contour" or isinstance(previous, int)):
            continue  # a discriminated union's tag, not a field
        if part in ("str", "EstimatorSpec", "literal['paper','recommended']"):
            continue
        text += ("." if text else "") + str(part)
    return text


def _friendly(error: dict[str, Any]) -> tuple[str, str]:
    """(field path, message) of one pydantic error."""
    loc = list(error["loc"])
    kind = error["type"]
    ctx = error.get("ctx") or {}
    if kind == "unknown_key":
        loc.append(str(ctx["key"]))
        return _loc_text(loc), f"unknown key; allowed: {ctx['allowed']}"
    if kind == "union_tag_invalid":
        return _loc_text(loc) + ".type", f"unknown type {ctx['tag']!r}; allowed: {ctx['expected_tags']}"
    if kind == "union_tag_not_found":
        return _loc_text(loc) + ".type", "missing; allowed: step, ramp, sine"
    if kind == "missing":
        if loc and isinstance(loc[-1], int):
            return _loc_text(loc[:-1]), f"too few items: item {loc[-1]} is missing"
        return _loc_text(loc), "required field is missing"
    msg = re.sub(r" or instance of \w+", "", error["msg"]).removeprefix("Value error, ")
    if kind in ("range", "order", "theta_order", "unknown_controller", "number_type"):
        return _loc_text(loc), _lower_first(msg)
    given = error.get("input")
    return _loc_text(loc), f"{_lower_first(msg)}, got {given!r}"


_MISMATCH = {"literal_error", "string_type", "model_type", "dict_type", "model_attributes_type"}


def _best_errors(errors: list[Any]) -> list[Any]:
    """Drop a union's "wrong branch" errors when another branch says what is really wrong."""
    real = [e for e in errors if e["type"] not in _MISMATCH]
    return real or errors


def _lower_first(text: str) -> str:
    return text[:1].lower() + text[1:] if text[:2] != text[:2].upper() else text


def _raise_validation(exc: ValidationError, source: str, prefix: Sequence[Any] = ()) -> None:
    errors = _best_errors(exc.errors())
    first = dict(errors[0])
    first["loc"] = (*prefix, *first["loc"])
    field, message = _friendly(first)
    if len(errors) > 1:
        message += f" (and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''})"
    raise ScenarioError(source, field, message) from None


def validate_data(data: dict[str, Any], source: str, default_name: str | None = None) -> Scenario:
    """Validate a parsed mapping into a Scenario and check the cross-field rules."""
    try:
        scenario = Scenario.model_validate(data)
    except ValidationError as exc:
        _raise_validation(exc, source)
    if scenario.name is None and default_name is not None:
        scenario = scenario.model_copy(update={"name": default_name})
    controller_options(scenario, source)
    _check_windows(scenario, source)
    _check_changes_and_monitor(scenario, source)
    return scenario


def _check_changes_and_monitor(scenario: Scenario, source: str) -> None:
    try:
        scenario.changes.plant_changes()
    except ValueError as exc:
        field, _, message = str(exc).partition(": ")
        raise ScenarioError(source, f"changes.{field}", message) from None
    m, d = scenario.monitor, scenario.duration_s
    if m.enable and m.baseline_summary is None and m.baseline_window_s[1] > d + 1e-9:
        a, b = m.baseline_window_s
        raise ScenarioError(source, "monitor.baseline_window_s",
                            f"must lie inside [0, duration_s = {_fmt(d)}] s, got [{_fmt(a)}, {_fmt(b)}] s "
                            "(or give monitor.baseline_summary)")  # fmt: skip


def _check_windows(scenario: Scenario, source: str) -> None:
    d = scenario.duration_s
    for field, given, window, what in (
        ("window_s", scenario.window_s, scenario.metric_window_s, "the second period [T, 2T]"),
        ("estimates_window_s", scenario.estimates_window_s, scenario.estimate_window_s, "the last period"),
    ):
        lo, hi = window
        if hi <= lo:
            raise ScenarioError(source, field, f"end must be after start, got [{_fmt(lo)}, {_fmt(hi)}] s")
        if lo < 0.0 or hi > d + 1e-9:
            if given is None:
                raise ScenarioError(
                    source,
                    field,
                    f"the default, {what} = [{lo:.4g}, {hi:.4g}] s, lies outside duration_s = "
                    f"{_fmt(d)} s; set {field} inside [0, {_fmt(d)}] s or lengthen duration_s",
                )
            raise ScenarioError(
                source, field, f"must lie inside [0, duration_s = {_fmt(d)}] s, got [{_fmt(lo)}, {_fmt(hi)}] s"
            )


def load_scenario(path: str | Path, overrides: Sequence[str] = (), controller: str | None = None) -> Scenario:
    """Read, override and validate a scenario file.

    ``controller`` (the command line's ``--controller``) replaces
    ``controller.name``; if it differs from the file's, the file's
    controller options are dropped (they belong to the other controller).
    ``overrides`` (``--set``) apply after that.
    """
    source = str(path)
    data = read_scenario_file(path)
    if controller is not None:
        current = data.get("controller")
        current = current if isinstance(current, dict) else {}
        if current.get("name", ControllerSpec().name) != controller:
            current = {}
        data["controller"] = {**current, "name": controller}
    data = apply_overrides(data, overrides, source)
    return validate_data(data, source, default_name=Path(path).stem)


def controller_options(scenario: Scenario, source: str = "<scenario>") -> dict[str, Any]:
    """Keyword arguments of the controller's factory, typed for the built-ins."""
    factory = factory_for(scenario.controller.name)
    schema = BUILTIN_OPTIONS.get(factory)
    if schema is None:
        return dict(scenario.controller.options)
    try:
        return schema.model_validate(scenario.controller.options).kwargs()
    except ValidationError as exc:
        _raise_validation(exc, source, ("controller", "options"))
    raise AssertionError("unreachable")


# ---------------------------------------------------------------------------
# Building the run.


@dataclass(frozen=True)
class BuiltRun:
    """Everything ``simulate`` needs, made from a scenario."""

    scenario: Scenario
    plant: Plant
    path: Ellipse
    timing: TimingLaw
    controller: Controller
    sensing: SensingConfig
    disturbance: Disturbance | None
    changes: ch.PlantChanges | None = None
    monitor: Any = None  # a fresh gantry_twin.monitor.MachineMonitor when monitor.enable


def build(scenario: Scenario, source: str = "<scenario>") -> BuiltRun:
    """Compile the plant, make the controller and check the contour fits the travel."""
    spec = scenario.payload
    changes = None if scenario.changes.empty else scenario.changes.plant_changes()
    payload_body = changes is not None and bool(changes.payload_change)
    plant = Plant(Payload(spec.mass_kg, tuple(spec.offset_m)), payload_body=payload_body)
    path = scenario.contour.path()
    _check_travel(plant, path, source)
    _check_samples(scenario, plant.timestep_s, source)
    kwargs = controller_options(scenario, source)
    try:
        controller = create(scenario.controller.name, **kwargs)
    except (TypeError, ValueError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        name = scenario.controller.name
        raise ScenarioError(source, "controller.options", f"rejected by {name!r}: {first}") from None
    disturbance = None if scenario.disturbance.empty else scenario.disturbance.function()
    monitor = make_monitor(scenario, controller, source) if scenario.monitor.enable else None
    return BuiltRun(scenario, plant, path, scenario.timing_law(), controller, scenario.sensing.config(), disturbance,
                    changes, monitor)  # fmt: skip


def make_monitor(scenario: Scenario, controller: Controller, source: str = "<scenario>") -> Any:
    """The MachineMonitor of a scenario: filters default to the controller's estimator's (DIARC)."""
    from gantry_twin.monitor import ExcitationSettings, HealthSettings, MachineMonitor

    m = scenario.monitor
    filter_hz = m.filter_hz
    if filter_hz is None:
        settings = getattr(controller, "estimator_settings", None) or EstimatorSettings()
        filter_hz = settings.filter_hz
    excitation = ExcitationSettings(window_s=m.excitation_window_s, filter_hz=tuple(filter_hz),
                                    min_parameter_v=m.min_parameter_v)  # fmt: skip
    tolerance = tuple([m.tolerance_pct / 100.0] * 6 + [m.tolerance_dn_v] * 2)
    health = HealthSettings(tolerance, m.decision_interval_s, tuple(m.baseline_window_s), m.judge_from_s)
    baseline = None
    if m.baseline_summary is not None:
        baseline = _baseline_from_summary(m.baseline_summary, source)
    return MachineMonitor(excitation, health, baseline)


def _baseline_from_summary(given: str, source: str) -> Any:
    """A commissioning run's estimates (its summary.json) as the monitor's baseline; path relative to the scenario."""
    import json

    from gantry_twin.monitor import Baseline

    path = Path(given)
    if not path.is_absolute() and Path(source).is_file():
        path = Path(source).parent / path
    field = "monitor.baseline_summary"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        estimates = {name: float(e["estimate"]) for name, e in data["estimates"].items()}
        return Baseline.from_mapping(estimates, f"commissioning run {path}")
    except OSError as exc:
        raise ScenarioError(source, field, f"cannot read {path} ({exc.strerror}); give a run's summary.json") from None
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ScenarioError(source, field, f"{path} is not a DIARC run's summary.json with estimates ({why})") from None


def _check_samples(scenario: Scenario, sample_period_s: float, source: str) -> None:
    """The run holds two samples and each window at least one (samples at k Ts, k < n)."""
    n = int(round(scenario.duration_s / sample_period_s))
    if n < 2:
        raise ScenarioError(
            source,
            "duration_s",
            f"must hold at least two samples of {sample_period_s:g} s, got {scenario.duration_s:g}",
        )
    t = np.arange(n) * sample_period_s
    for field, (lo, hi) in (("window_s", scenario.metric_window_s), ("estimates_window_s", scenario.estimate_window_s)):
        if not np.any((t >= lo) & (t < hi)):
            raise ScenarioError(
                source, field, f"[{lo:g}, {hi:g}) s holds no sample; samples are at multiples of {sample_period_s:g} s"
            )


def _check_travel(plant: Plant, path: Ellipse, source: str) -> None:
    """Every point of the contour within the joint range less a margin."""
    ranges = plant.model.jnt_range
    joints = [plant.model.joint(a).id for a in AXES]
    phi = np.linspace(0.0, path.period_rad, 721)
    p, *_ = path.derivatives(phi)
    for axis, (name, joint) in enumerate(zip(AXES, joints, strict=True)):
        lo, hi = ranges[joint] + np.array([TRAVEL_MARGIN_M, -TRAVEL_MARGIN_M])
        reach = (float(p[:, axis].min()), float(p[:, axis].max()))
        if reach[0] < lo - 1e-12 or reach[1] > hi + 1e-12:
            raise ScenarioError(
                source,
                "contour",
                f"the path spans {name} in [{reach[0]:.4g}, {reach[1]:.4g}] m; the travel allows "
                f"[{lo:.4g}, {hi:.4g}] m (joint range less {TRAVEL_MARGIN_M * 1e3:g} mm); shrink or move it",
            )


# ---------------------------------------------------------------------------
# Shipped scenarios.


def scenarios_dir() -> Path:
    """The shipped scenarios: ``gantry_twin/scenarios`` in a wheel, ``scenarios/`` in a checkout."""
    packaged = resources.files("gantry_twin") / "scenarios"
    if packaged.is_dir():
        return Path(str(packaged))
    return Path(__file__).resolve().parents[2] / "scenarios"


def shipped_scenarios() -> list[Path]:
    """Paths of the shipped scenario files, sorted by name."""
    return sorted(scenarios_dir().glob("*.yaml"))


def shipped(name: str) -> Path:
    """The shipped scenario called ``name`` (with or without ``.yaml``)."""
    return scenarios_dir() / (name if name.endswith(".yaml") else f"{name}.yaml")


def dump_yaml(data: dict[str, Any]) -> str:
    """Stable YAML text (key order kept, block style)."""
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, allow_unicode=True)
