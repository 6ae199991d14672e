"""The scenario schema: what a scenario file may say, field by field.

The domain settings are fields of their own types (:class:`Payload`,
:class:`PlantSettings` (the friction model), :class:`SensingConfig`,
:class:`PlantChanges`, and the built-in controllers'
``gains``, ``estimator``, ...): their ranges are declared once, on those
types (:mod:`gantry_twin.settings`). What exists only in a scenario (the
contour and its timing, disturbance events, the monitor switch and windows,
outputs) is declared here as pydantic models. Unknown keys are rejected with
the list of allowed keys.
"""

from __future__ import annotations

import functools
import inspect
import math
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, get_type_hints

import numpy as np
from pydantic import Field, create_model, model_validator
from pydantic_core import PydanticCustomError

from gantry_twin.controllers import available
from gantry_twin.gcode.planner import AxisLimits, PlanOptions, default_limits, plan_program
from gantry_twin.gcode.reader import Program, read_program
from gantry_twin.gcode.sampling import Plan
from gantry_twin.gcode.tools import Tool, read_tool_table
from gantry_twin.health.excitation import ExcitationSettings, ExcitationWindowS, MinParameterV
from gantry_twin.health.monitor import DecisionIntervalS, HealthSettings
from gantry_twin.loop.simulate import Disturbance
from gantry_twin.numerics import libm
from gantry_twin.numerics.estimation import FilterHz
from gantry_twin.paths.contours import Ellipse, TimingLaw
from gantry_twin.plant.faults import PlantChanges
from gantry_twin.plant.model import Payload, PlantSettings
from gantry_twin.plant.sensing import SensingConfig
from gantry_twin.settings import VOLTS_MAX_V, Frequency, Label, Model, Range, Real, Seconds, Window, quote

#: Longest run accepted, s (30 s is the paper's; an hour is 18 M samples).
DURATION_MAX_S = 3600.0
#: A disturbance event's volts.
Volts = Range(-VOLTS_MAX_V, VOLTS_MAX_V, "V")


# ---------------------------------------------------------------------------
# The contour and its timing.


class TimingSpec(Model):
    """phi(t): constant rate after an optional smooth start (docs/equations.md, contour and timing law)."""

    rate_rad_s: Range(0.0, 20.0, "rad/s", lo_open=True) | None = None
    start: Literal["on_path", "rest"] = "on_path"
    ramp_s: Range(0.0, 60.0, "s", lo_open=True) = 0.5


Point2 = tuple[Real, Real]
Extent = Range(0.0, 1.0, "m", lo_open=True)
#: The work coordinate systems a scenario may offset (gcode.machine.SYSTEMS).
WORK_SYSTEMS = ("G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3")


class CircleSpec(Model):
    """The paper's circle (5.1): radius 0.2 m at 2 rad/s (0.4 m/s)."""

    type: Literal["circle"] = "circle"
    radius_m: Extent = 0.2
    centre_m: Point2 = (0.0, 0.0)
    timing: TimingSpec = TimingSpec()

    default_rate_rad_s: ClassVar[float] = 2.0

    def path(self) -> Ellipse:
        return Ellipse(self.radius_m, self.radius_m, tuple(self.centre_m))


class EllipseSpec(Model):
    """p(phi) = centre + [a sin phi, -b cos phi]; the paper's (5.2) at 3 rad/s."""

    type: Literal["ellipse"] = "ellipse"
    semi_x_m: Extent = 0.2
    semi_y_m: Extent = 0.1
    centre_m: Point2 = (0.0, 0.1)
    timing: TimingSpec = TimingSpec()

    default_rate_rad_s: ClassVar[float] = 3.0

    def path(self) -> Ellipse:
        return Ellipse(self.semi_x_m, self.semi_y_m, tuple(self.centre_m))


PathSpeed = Range(0.0, 100.0, "m/s", lo_open=True)
PathAcceleration = Range(0.0, 1e5, "m/s^2", lo_open=True)
PathJerk = Range(0.0, 1e8, "m/s^3", lo_open=True)


class LimitsSpec(Model):
    """Per-axis (X, Y) limits of a planned program's reference (gantry_twin.gcode.planner.AxisLimits)."""

    velocity_m_s: tuple[PathSpeed, PathSpeed]
    acceleration_m_s2: tuple[PathAcceleration, PathAcceleration]
    jerk_m_s3: tuple[PathJerk, PathJerk]

    def limits(self) -> AxisLimits:
        return AxisLimits(tuple(self.velocity_m_s), tuple(self.acceleration_m_s2), tuple(self.jerk_m_s3))


class GcodeTimingSpec(Model):
    """A program's timing is its plan: phi = t (``TimingLaw(1.0)``); nothing to set."""

    rate_rad_s: Literal[1.0] = 1.0
    start: Literal["on_path"] = "on_path"
    ramp_s: Literal[0.5] = 0.5


class GcodeSpec(Model):
    """A part program (docs/gcode.md): ``file`` (relative to the scenario file) read, planned and run.

    limits: the reference's per-axis limits (default: derived from the
    plant, :func:`gantry_twin.gcode.planner.default_limits`); rapid_limits
    for G0 (default: limits); pivot_s: how long the task frame takes to turn
    at a stop; drop_unsupported: drop Z, spindle and coolant words and a
    drilling cycle's Z part instead of refusing the program; block_delete:
    skip the lines that start with ``/`` (LinuxCNC's default); max_blocks:
    the blocks executed before a program is stopped as endless;
    subroutine_path: directories (relative to the scenario file) searched
    for ``NAME.ngc`` before the program's own; work_offsets: G54 ... G59.3
    -> (x, y) mm, the work offsets at the start (machine coordinates of
    each system's origin); tool_table: a LinuxCNC tool table (relative to
    the scenario file; docs/gcode.md, "Cutter radius compensation") and
    tools: tool number -> diameter mm, beside or instead of it (an entry
    here replaces the table's), for G41 / G42. cnc: who reads and plans the
    program: ``twin`` (the twin's reader and planner) or ``linuxcnc``
    (LinuxCNC runs it and the twin tracks its recorded commands;
    docs/linuxcnc.md); cnc_ini: a LinuxCNC INI (relative to the scenario
    file) whose limits LinuxCNC plans with (default: the twin's machine).
    """

    type: Literal["gcode"] = "gcode"
    file: str
    drop_unsupported: bool = False
    block_delete: bool = True
    max_blocks: Range(1, 100_000_000, "blocks") = 1_000_000
    subroutine_path: list[str] = []
    work_offsets: dict[Literal[WORK_SYSTEMS], tuple[Range(-1e4, 1e4, "mm"), Range(-1e4, 1e4, "mm")]] = {}
    tool_table: str | None = None
    tools: dict[Range(1, 99_999, "tool number"), Range(-1000.0, 1000.0, "mm")] = {}
    limits: LimitsSpec | None = None
    rapid_limits: LimitsSpec | None = None
    pivot_s: Range(0.0, 1.0, "s", lo_open=True) = 0.02
    cnc: Literal["twin", "linuxcnc"] = "twin"
    cnc_ini: str | None = None
    timing: GcodeTimingSpec = GcodeTimingSpec()

    default_rate_rad_s: ClassVar[float] = 1.0

    def plan(self, base_dir: Path | None = None, program: Program | None = None) -> Plan:
        """Read (unless given) and plan the program (raises :class:`~gantry_twin.gcode.GcodeError`)."""
        options = PlanOptions(
            limits=self.limits.limits() if self.limits else default_limits(),
            rapid_limits=self.rapid_limits.limits() if self.rapid_limits else None,
            pivot_s=self.pivot_s,
        )
        return plan_program(program if program is not None else self.read(base_dir), options)

    def read(self, base_dir: Path | None = None) -> Program:
        """Read the program (raises :class:`~gantry_twin.gcode.GcodeError`)."""

        def here(name: str) -> Path:
            return self.here(name, base_dir)

        tools = read_tool_table(here(self.tool_table)) if self.tool_table is not None else {}
        for number, diameter_mm in self.tools.items():
            tools[int(number)] = Tool(int(number), 0, diameter_mm * 1e-3)
        return read_program(
            here(self.file), drop_unsupported=self.drop_unsupported, block_delete=self.block_delete,
            max_blocks=int(self.max_blocks), subroutine_path=tuple(here(d) for d in self.subroutine_path),
            work_offsets_mm={WORK_SYSTEMS.index(k) + 1: tuple(v) for k, v in self.work_offsets.items()},
            tools=tools,
        )  # fmt: skip

    def path(self) -> Plan:
        return self.plan()

    @staticmethod
    def here(name: str, base_dir: Path | None) -> Path:
        """A file named in the spec: relative to the scenario file's directory ``base_dir`` (if any)."""
        path = Path(name)
        return base_dir / path if base_dir is not None and not path.is_absolute() else path


ContourSpec = Annotated[CircleSpec | EllipseSpec | GcodeSpec, Field(discriminator="type")]


# ---------------------------------------------------------------------------
# Disturbance events.


class _Event(Model):
    start_s: Seconds = 0.0
    end_s: Seconds | None = None

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
    value_v: Volts
    start_s: Seconds = 0.0
    end_s: Seconds | None = None

    def volts(self, t: np.ndarray) -> np.ndarray:
        return np.where(self._active(t), self.value_v, 0.0)


class RampEvent(_Event):
    """Linear from from_v at start_s to to_v at end_s, zero outside [start_s, end_s)."""

    type: Literal["ramp"] = "ramp"
    from_v: Volts = 0.0
    to_v: Volts
    start_s: Seconds = 0.0
    end_s: Seconds

    def volts(self, t: np.ndarray) -> np.ndarray:
        frac = (t - self.start_s) / (self.end_s - self.start_s)
        return np.where(self._active(t), self.from_v + (self.to_v - self.from_v) * frac, 0.0)


class SineEvent(_Event):
    """amplitude_v sin(2 pi frequency_hz t + phase_rad) on [start_s, end_s), t the run time."""

    type: Literal["sine"] = "sine"
    amplitude_v: Volts
    frequency_hz: Frequency
    phase_rad: Real = 0.0
    start_s: Seconds = 0.0
    end_s: Seconds | None = None

    def volts(self, t: np.ndarray) -> np.ndarray:
        wave = self.amplitude_v * libm.sin(2.0 * np.pi * self.frequency_hz * t + self.phase_rad)
        return np.where(self._active(t), wave, 0.0)


EventSpec = Annotated[StepEvent | RampEvent | SineEvent, Field(discriminator="type")]
#: The ``type`` tags of the two discriminated unions (pydantic puts them in an error's location).
CONTOUR_TYPES = tuple(m.model_fields["type"].default for m in (CircleSpec, EllipseSpec, GcodeSpec))
EVENT_TYPES = tuple(m.model_fields["type"].default for m in (StepEvent, RampEvent, SineEvent))


class DisturbanceSpec(Model):
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


# ---------------------------------------------------------------------------
# Controller, monitor, outputs.


class ControllerSpec(Model):
    """A controller by registry name and the keyword options of its factory."""

    name: str = "diarc"
    options: dict[str, Any] = {}

    @model_validator(mode="after")
    def _known_name(self) -> ControllerSpec:
        names = available()
        if self.name not in names:
            raise PydanticCustomError(
                "unknown_controller",
                "unknown controller {name}; available: {names}",
                {"name": quote(self.name), "names": ", ".join(names)},
            )
        return self


_HEALTH = HealthSettings()
_EXCITATION = ExcitationSettings()


class MonitorSpec(Model):
    """The excitation and health monitor (gantry_twin.health.monitor, docs/health.md).

    Its fields are those of :class:`ExcitationSettings` and
    :class:`HealthSettings` (same types and defaults), except the tolerance,
    given as one relative value for M, B, Af and one in volts for dN.
    """

    enable: bool = False
    baseline_window_s: Window = _HEALTH.baseline_window_s
    baseline_summary: str | None = None
    judge_from_s: Seconds | None = _HEALTH.judge_from_s
    tolerance_pct: Range(0.0, 100.0, "%", lo_open=True) = 100.0 * _HEALTH.tolerance[0]
    tolerance_dn_v: Range(0.0, VOLTS_MAX_V, "V", lo_open=True) = _HEALTH.tolerance[6]
    decision_interval_s: DecisionIntervalS = _HEALTH.decision_interval_s
    excitation_window_s: ExcitationWindowS = _EXCITATION.window_s
    min_parameter_v: MinParameterV = _EXCITATION.min_parameter_v
    filter_hz: FilterHz | None = None


class OutputsSpec(Model):
    """Where and what ``gantry-twin run`` writes: ``runs/<dir>/`` (default ``runs/<name>/``) unless ``--out``."""

    dir: Label | None = None
    trace: bool = True
    trace_stride: Annotated[int, Field(ge=1, le=100000)] = 1


# ---------------------------------------------------------------------------
# The whole run.


class Scenario(Model):
    """A whole run. Every field has a default; see docs/scenarios.md."""

    name: Label | None = None
    description: str = ""
    contour: ContourSpec = CircleSpec()
    payload: Payload = Payload()
    plant: PlantSettings = PlantSettings()
    disturbance: DisturbanceSpec = DisturbanceSpec()
    controller: ControllerSpec = ControllerSpec()
    sensing: SensingConfig = SensingConfig()
    duration_s: Range(0.0, DURATION_MAX_S, "s", lo_open=True) = 30.0
    window_s: Window | None = None
    estimates_window_s: Window | None = None
    changes: PlantChanges = PlantChanges()
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
        """window_s, or by default the paper's second period [t0 + T, t0 + 2T] (t0: end of the start ramp)
        when the run holds it; in a shorter run the last whole period [d - T, d] after t0, else the run after
        the ramp [t0, d] (docs/scenarios.md, "Windows")."""
        if self.window_s is not None:
            return (float(self.window_s[0]), float(self.window_s[1]))
        t0, period, d = self.timing_law().settled_s, self.period_s, self.duration_s
        if t0 + 2.0 * period <= d + 1e-9:
            return (t0 + period, t0 + 2.0 * period)
        if d - period >= t0:
            return (d - period, d)
        return (t0, d) if d > t0 else (0.0, d)

    @property
    def metric_window_is_papers(self) -> bool:
        """True when :attr:`metric_window_s` is the paper's second period (no window_s, and the run holds it)."""
        t0, period = self.timing_law().settled_s, self.period_s
        return self.window_s is None and t0 + 2.0 * period <= self.duration_s + 1e-9

    @property
    def estimate_window_s(self) -> tuple[float, float]:
        """estimates_window_s, or the last period [d - T, d]; in a run shorter than that, the run after the
        start ramp [t0, d] (else the whole run)."""
        if self.estimates_window_s is not None:
            return (float(self.estimates_window_s[0]), float(self.estimates_window_s[1]))
        d, period = self.duration_s, self.period_s
        if d - period >= 0.0:
            return (d - period, d)
        t0 = self.timing_law().settled_s
        return (t0, d) if d > t0 else (0.0, d)

    def resolved(self) -> dict[str, Any]:
        """Every field with its value (defaults and windows filled in), JSON-compatible."""
        data = self.model_dump(mode="json")
        data["contour"]["timing"]["rate_rad_s"] = self.rate_rad_s
        data["window_s"] = list(self.metric_window_s)
        data["estimates_window_s"] = list(self.estimate_window_s)
        return data


# ---------------------------------------------------------------------------
# Controller options: a built-in's are the keyword arguments of its factory, typed by
# the factory's own annotations; a plug-in's pass through untyped.


@functools.cache
def typed_options(factory: Any) -> type[Model] | None:
    """A model of the factory's keyword arguments, for a built-in (defined in gantry_twin); None for a plug-in."""
    if not str(getattr(factory, "__module__", "")).startswith("gantry_twin."):
        return None
    hints = get_type_hints(factory.__init__ if inspect.isclass(factory) else factory, include_extras=True)
    fields = {
        name: (hints.get(name, Any), None if p.default is inspect.Parameter.empty else p.default)
        for name, p in inspect.signature(factory).parameters.items()
        if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    }
    return create_model(f"{factory.__name__}Options", __base__=Model, **fields)
