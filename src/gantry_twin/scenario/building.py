"""Building a run: a validated :class:`Scenario` -> the plant, path, controller, ... ``simulate`` takes.

What needs the compiled model is checked here: the contour inside the
travel, each window holding a sample; and the controller's factory gets
its options (an exception from a plug-in's factory is reported against
``controller.options``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gantry_twin.cnc.canon import read_canon
from gantry_twin.cnc.config import CncConfigError, machine_from_ini, twin_machine
from gantry_twin.cnc.offline import run_program
from gantry_twin.cnc.reference import CncPath, read_run_files
from gantry_twin.cnc.session import LinuxCncError
from gantry_twin.cnc.session import missing as linuxcnc_missing
from gantry_twin.controllers import Controller, EstimatorSettings, PluginError, create
from gantry_twin.gcode.program import TRAVEL_MARGIN_M
from gantry_twin.gcode.reader import GcodeError
from gantry_twin.health.confidence import EstimateConfidence
from gantry_twin.health.monitor import Baseline, ExcitationSettings, HealthSettings, MachineMonitor
from gantry_twin.loop.simulate import Disturbance
from gantry_twin.numerics.estimation import FRICTION_SLOPE_S_M
from gantry_twin.outputs.summary import RunSummary, SummaryError
from gantry_twin.paths.contours import Contour, Ellipse, TimingLaw
from gantry_twin.plant.faults import PlantChanges
from gantry_twin.plant.friction import FrictionError
from gantry_twin.plant.model import AXES, Plant, default_model_path
from gantry_twin.plant.sensing import SensingConfig
from gantry_twin.scenario.errors import ScenarioError
from gantry_twin.scenario.loading import controller_options
from gantry_twin.scenario.schema import GcodeSpec, Scenario
from gantry_twin.settings import quote, shorten


@dataclass(frozen=True)
class BuiltRun:
    """Everything ``simulate`` needs, made from a scenario."""

    scenario: Scenario
    plant: Plant
    path: Contour
    timing: TimingLaw
    controller: Controller
    sensing: SensingConfig
    disturbance: Disturbance | None
    changes: PlantChanges | None = None
    monitor: MachineMonitor | None = None  # a fresh one when monitor.enable

    @property
    def duration_s(self) -> float:
        """How long to simulate: a planned program's duration (it follows from the plan), else the scenario's."""
        return self.scenario.duration_s  # a part program's: its plan's (build sets it)


def build(scenario: Scenario, source: str = "<scenario>") -> BuiltRun:
    """Compile the plant, make the controller and check the contour fits the travel."""
    changes = None if scenario.changes.empty else scenario.changes
    payload_body = changes is not None and bool(changes.payload_change)
    plant = scenario_plant(scenario, payload_body, source)
    path = _contour_path(scenario, source)
    scenario = _follow_the_plan(scenario, path, plant.timestep_s, source)
    _check_travel(plant, path, source)
    _check_samples(scenario, plant.timestep_s, source)
    kwargs = controller_options(scenario, source)
    scenario, kwargs = _controller_files(scenario, kwargs, source)
    try:
        controller = create(scenario.controller.name, **kwargs)
    except PluginError as exc:  # its module is missing, raised at import, or its factory raised or exited
        raise ScenarioError(source, "controller.name", shorten(str(exc), 200)) from None
    except (TypeError, ValueError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        name = scenario.controller.name
        raise ScenarioError(source, "controller.options", f"rejected by {quote(name)}: {shorten(first, 120)}") from None
    disturbance = None if scenario.disturbance.empty else scenario.disturbance.function()
    monitor = make_monitor(scenario, controller, source) if scenario.monitor.enable else None
    return BuiltRun(
        scenario, plant, path, scenario.timing_law(), controller, scenario.sensing, disturbance, changes, monitor
    )


def _controller_files(scenario: Scenario, kwargs: dict[str, object], source: str) -> tuple[Scenario, dict[str, object]]:
    """A built-in controller's options typed as files (``pathlib.Path``: the FMU of ``controller: {name: fmu}``)
    are relative to the scenario file; they are named by their absolute path from here on (so that the run's
    scenario.yaml finds them from anywhere), as a part program's file is."""
    if not Path(source).is_file():
        return scenario, kwargs
    base = Path(source).parent
    files = {k: (base / v).resolve() for k, v in kwargs.items() if isinstance(v, Path) and not v.is_absolute()}
    if not files:
        return scenario, kwargs
    options = {**scenario.controller.options, **{k: str(v) for k, v in files.items()}}
    controller = scenario.controller.model_copy(update={"options": options})
    return scenario.model_copy(update={"controller": controller}), {**kwargs, **files}


def _follow_the_plan(scenario: Scenario, path: Contour, timestep_s: float, source: str = "") -> Scenario:
    """A part program's run lasts its plan (whole samples); its default windows are the whole program (contour
    error) and its second half (estimates); its files (program, INI, tool table, subroutine directories) are
    named by their absolute paths (so that the run's scenario.yaml finds them from anywhere: compare plans it
    again). Other contours keep the scenario as it is."""
    if not isinstance(scenario.contour, GcodeSpec):
        return scenario
    d = max(math.ceil(float(path.duration_s) / timestep_s), 2) * timestep_s
    update: dict[str, object] = {"duration_s": d}
    if Path(source).is_file():  # its files by their absolute paths
        contour, here = scenario.contour, Path(source).parent

        def absolute(name: str) -> str:
            return name if Path(name).is_absolute() else str((here / name).resolve())

        named = {"file": contour.file, "cnc_ini": contour.cnc_ini, "tool_table": contour.tool_table}
        files: dict[str, object] = {k: absolute(v) for k, v in named.items() if v}
        if contour.subroutine_path:
            files["subroutine_path"] = [absolute(d) for d in contour.subroutine_path]
        update["contour"] = contour.model_copy(update=files)
    if scenario.window_s is None:
        update["window_s"] = (0.0, d)
    if scenario.estimates_window_s is None:
        update["estimates_window_s"] = (0.5 * d, d)
    return scenario.model_copy(update=update)


def _contour_path(scenario: Scenario, source: str) -> Contour:
    """The contour's path; a part program (``type: gcode``) read relative to the scenario file and planned."""
    contour = scenario.contour
    if not isinstance(contour, GcodeSpec):
        return contour.path()
    base = Path(source).parent if Path(source).is_file() else None
    try:
        if contour.cnc == "linuxcnc":
            return _linuxcnc_path(contour, base, source)
        return contour.plan(base)
    except GcodeError as exc:
        raise ScenarioError(source, "contour.file", str(exc)) from None


def _linuxcnc_path(contour: GcodeSpec, base: Path | None, source: str) -> CncPath:
    """The program run by LinuxCNC (docs/linuxcnc.md): its recorded commands as the reference. LinuxCNC's own
    failures (:class:`~gantry_twin.cnc.session.LinuxCncError`) are raised as they are: not the scenario's."""
    why = linuxcnc_missing()
    if why is not None:
        raise ScenarioError(source, "contour.cnc", f"linuxcnc: {why}")
    try:
        machine = twin_machine() if contour.cnc_ini is None else machine_from_ini(contour.here(contour.cnc_ini, base))
    except CncConfigError as exc:
        raise ScenarioError(source, "contour.cnc_ini", str(exc)) from None
    program, table, subroutines = _program_files(contour, base)
    return CncPath(run_program(program, machine, table, subroutine_path=subroutines))


def _program_files(contour: GcodeSpec, base: Path | None) -> tuple[Path, Path | None, tuple[Path, ...]]:
    """The program, its tool table (None: none) and subroutine directories, relative to ``base``."""
    table = contour.here(contour.tool_table, base) if contour.tool_table is not None else None
    return contour.here(contour.file, base), table, tuple(contour.here(d, base) for d in contour.subroutine_path)


def recorded_linuxcnc_path(contour: GcodeSpec, run_dir: Path, source: str) -> CncPath:
    """The path a run that LinuxCNC drove followed, from its run files
    (:func:`gantry_twin.cnc.reference.read_run_files`) and its program read by rs274 again: its part figure
    measures against LinuxCNC's moves at LinuxCNC's times, as the run did. ScenarioError where rs274 refuses
    the program now, OSError where rs274 is missing or a file cannot be read, ValueError for the run's files."""
    try:
        canon = read_canon(*_program_files(contour, run_dir))
    except (GcodeError, LinuxCncError) as exc:
        raise ScenarioError(source, "contour.file", str(exc)) from None
    return CncPath(read_run_files(run_dir, canon))


def scenario_plant(scenario: Scenario, payload_body: bool, source: str) -> Plant:
    """The compiled plant: the shipped model (``plant.model``), or ``plant.file`` (relative to the scenario file),
    with the scenario's friction, offset and ripple where given (else the file's own)."""
    settings = scenario.plant
    properties = {
        "friction": settings.friction,
        "offset": settings.offset,
        "ripple": settings.ripple,
        "amplifier": settings.amplifier,
    }
    if settings.file is None:
        path = default_model_path(settings.model)
        return _with_friction(
            lambda: Plant(scenario.payload, model_path=path, payload_body=payload_body, **properties), source
        )
    path = Path(settings.file)
    if not path.is_absolute() and Path(source).is_file():
        path = Path(source).parent / path
    if not path.is_file():
        raise ScenarioError(source, "plant.file", f"{quote(str(path))}: no such file; give an MJCF model of the gantry")
    try:
        return _with_friction(
            lambda: Plant(scenario.payload, model_path=path, payload_body=payload_body, **properties), source
        )
    except ScenarioError:  # a friction setting this model refuses: already names its field
        raise
    except (ValueError, KeyError, TypeError) as exc:  # mujoco's errors, a missing named element
        why = shorten(str(exc).splitlines()[0] if str(exc) else type(exc).__name__, 120)
        raise ScenarioError(source, "plant.file", f"{quote(str(path))} is not a gantry model ({why})") from None


def _with_friction(make: Callable[[], Plant], source: str) -> Plant:
    """``make()``, with a friction setting the compiled model refuses as a ScenarioError naming its field."""
    try:
        return make()
    except FrictionError as exc:
        raise ScenarioError(source, f"plant.{exc.field}", exc.message) from None


def excitation_settings(scenario: Scenario, controller: Controller) -> ExcitationSettings:
    """How the monitor and the estimates' confidence see the estimator's regression: the filters (the scenario's
    ``monitor.filter_hz`` or the controller's estimator's), friction shape and reversal gate of the controller's
    estimator (DIARC; the paper's otherwise), and the encoder's resolution."""
    m, sensing = scenario.monitor, scenario.sensing
    settings = getattr(controller, "estimator_settings", None) or EstimatorSettings()
    gains = getattr(controller, "gains", None)
    slope = settings.friction_slope_s_m
    if slope is None:
        slope = gains.friction_slope_s_m if gains is not None else FRICTION_SLOPE_S_M
    return ExcitationSettings(
        window_s=m.excitation_window_s,
        filter_hz=tuple(settings.filter_hz if m.filter_hz is None else m.filter_hz),
        filter_zeta=settings.filter_zeta,
        friction_slope_s_m=slope,
        reversal_gate=settings.reversal_gate,
        resolution_m=sensing.resolution_m if sensing.quantize else 0.0,
        min_parameter_v=m.min_parameter_v,
    )


def estimate_confidence(built: BuiltRun) -> EstimateConfidence | None:
    """The estimates' confidence over the estimates window, for a controller with an indirect estimator (DIARC)."""
    if getattr(built.controller, "estimator_settings", None) is None:
        return None
    return EstimateConfidence(excitation_settings(built.scenario, built.controller), built.scenario.estimate_window_s)


def make_monitor(scenario: Scenario, controller: Controller, source: str = "<scenario>") -> MachineMonitor:
    """The MachineMonitor of a scenario: it sees the controller's estimator (:func:`excitation_settings`)."""
    m = scenario.monitor
    excitation = excitation_settings(scenario, controller)
    tolerance = tuple([m.tolerance_pct / 100.0] * 6 + [m.tolerance_dn_v] * 2)
    health = HealthSettings(tolerance, m.decision_interval_s, tuple(m.baseline_window_s), m.judge_from_s)
    baseline = None
    if m.baseline_summary is not None:
        baseline = _baseline_from_summary(m.baseline_summary, source)
    return MachineMonitor(excitation, health, baseline)


def _baseline_from_summary(given: str, source: str) -> Baseline:
    """A commissioning run's estimates (its summary.json) as the monitor's baseline; path relative to the scenario."""
    path = Path(given)
    if not path.is_absolute() and Path(source).is_file():
        path = Path(source).parent / path
    field = "monitor.baseline_summary"
    try:
        summary = RunSummary.read(path)
    except SummaryError as exc:
        raise ScenarioError(source, field, f"{quote(str(path))}: {exc.reason}") from None
    try:
        estimates = {name: e.estimate for name, e in (summary.estimates or {}).items()}
        return Baseline.from_mapping(estimates, f"commissioning run {path}")
    except ValueError as exc:
        why = shorten(str(exc).splitlines()[0] if str(exc) else type(exc).__name__, 120)
        raise ScenarioError(
            source, field, f"{quote(str(path))} is not a DIARC run's summary.json with estimates ({why})"
        ) from None


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
