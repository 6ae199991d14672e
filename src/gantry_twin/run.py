"""Running a built scenario and writing its outputs (used by the CLI, the report and sweeps).

The output contract (docs/cli.md): a directory that holds ``summary.json``
holds exactly one complete run. :class:`RunWriter` keeps it: it checks that
the directory can be written before anything runs, writes the trace as the
run goes (a hidden temporary file), and at the end deletes the old
summary.json, puts the new files in place, removes the files of an earlier
run that this run does not write, and writes summary.json last (the figures,
``plots/``, before it, when asked for: :mod:`gantry_twin.outputs.plots`). An
interrupted run removes its temporary files (and a directory it made and
left empty); a run stopped by a fault (:class:`SimulationError`) is written
with the trace up to the fault and ``status: failed``.
"""

from __future__ import annotations

import json
import platform
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

from gantry_twin.cnc.reference import CNC_COMMANDS_FILE, CNC_FILE
from gantry_twin.controllers.base import compiled_step_of
from gantry_twin.gcode.part_error import PartErrorWatch
from gantry_twin.gcode.sampling import ProgramPath
from gantry_twin.loop.events import TravelWatch
from gantry_twin.loop.simulate import sample_count, simulate
from gantry_twin.loop.trace import Observer, SimulationError, Trace
from gantry_twin.metrics import RunMetrics
from gantry_twin.outputs.files import (
    atomic_write_text,
    discard,
    remove_stale_temporaries,
    remove_tree,
    temporary_file,
)
from gantry_twin.outputs.signals import SwallowedInterrupt, signals_held
from gantry_twin.outputs.summary import Failure, RunSummary, run_summary, summary_json
from gantry_twin.outputs.tracefile import TRACE_COLUMNS, TRACE_FILE, TraceWriter, stored_row_bytes
from gantry_twin.plant.model import THETA_NAMES
from gantry_twin.scenario import BuiltRun, dump_yaml
from gantry_twin.scenario.building import estimate_confidence

#: The files :class:`RunWriter` leaves in a run's directory (docs/cli.md); summary.json is written last.
SUMMARY_FILE = "summary.json"
SCENARIO_FILE = "scenario.yaml"
RUN_INFO_FILE = "run_info.json"
RUN_FILES = (SUMMARY_FILE, SCENARIO_FILE, TRACE_FILE, RUN_INFO_FILE, CNC_FILE, CNC_COMMANDS_FILE)
#: The directory of a run's figures (:mod:`gantry_twin.outputs.plots`), written before summary.json when asked for.
PLOTS_DIR = "plots"

#: How much of a run :func:`run_and_write` holds in memory, s: the trace goes to disk a piece (row group) at a time.
HOLD_S = 10.0
#: A trace.parquet larger than this, bytes (before compression), is announced before the run with the trace_stride hint.
LARGE_TRACE_BYTES = 10**9


def execute(built: BuiltRun, observers: Sequence[Observer] = ()) -> Trace:
    """Simulate a built scenario; the whole trace, in memory."""
    return _simulate(built, observers)


def _simulate(
    built: BuiltRun, observers: Sequence[Observer], hold_s: float | None = None, chunk_s: float | None = None
) -> Trace:
    s = built.scenario
    if built.monitor is not None:
        # First, so that observers after it (telemetry) see this chunk's alarms.
        observers = [built.monitor, *observers]
        for observer in observers:
            if hasattr(observer, "watch"):
                observer.watch(built.monitor)
    return simulate(
        built.plant,
        built.path,
        built.timing,
        built.controller,
        duration_s=s.duration_s,
        sensing=built.sensing,
        disturbance=built.disturbance,
        observers=observers,
        controller_name=s.controller.name,
        changes=built.changes,
        hold_s=hold_s,
        **({} if chunk_s is None else {"chunk_s": chunk_s}),  # simulate's own default otherwise
    )


class TraceSize(NamedTuple):
    """How large a run's trace.parquet can be: the run's samples, outputs.trace_stride, columns (at least:
    a Python controller's log is known only once it runs), bytes per row before compression
    (:func:`gantry_twin.outputs.tracefile.stored_row_bytes`); compression only makes the file smaller."""

    samples: int
    stride: int
    columns: int
    row_bytes: int

    @property
    def rows(self) -> int:
        return -(-self.samples // self.stride)

    @property
    def bytes(self) -> int:
        return self.rows * self.row_bytes

    def stride_under(self, limit_bytes: int = LARGE_TRACE_BYTES) -> int:
        """An outputs.trace_stride that keeps the trace under ``limit_bytes``."""
        return max(self.stride + 1, -(-self.samples * self.row_bytes // limit_bytes))


def trace_size(built: BuiltRun) -> TraceSize:
    """The size of the trace.parquet the scenario will write (no columns with outputs.trace false)."""
    outputs = built.scenario.outputs
    n = sample_count(built.scenario.duration_s, built.plant.timestep_s)
    if not outputs.trace:
        return TraceSize(n, outputs.trace_stride, 0, 0)
    compiled = compiled_step_of(built.controller)
    logged = compiled.log_size if compiled is not None else 0
    moving = built.changes is not None and not built.changes.empty
    others = logged + (len(THETA_NAMES) if moving else 0)
    return TraceSize(n, outputs.trace_stride, len(TRACE_COLUMNS) + others, stored_row_bytes(others))


class RunOutcome(NamedTuple):
    """What :func:`run_and_write` did: summary.json's content, wall time s (the compile of the loop not counted),
    the files written (in ``out``), the error that stopped a failed run."""

    summary: RunSummary
    wall_time_s: float
    files: tuple[str, ...]
    error: SimulationError | None = None

    @property
    def failed(self) -> bool:
        return self.summary.failed


class RunWriter:
    """Writes one run into ``out`` by the output contract (module docstring); a context manager that
    removes what it started if the block fails.

    Creating it makes the directory and checks it can be written (OSError if
    not); its :meth:`observers` gather the summary's metrics and write the
    trace during the run; :meth:`finish` writes the rest.
    """

    def __init__(
        self,
        out: Path,
        built: BuiltRun,
        overrides: Sequence[str] = (),
        controller_option: str | None = None,
        plots: bool = False,
        plot_format: str = "png",
        plot_dpi: float = 150.0,
    ) -> None:
        self.out, self.built = Path(out), built
        self.overrides, self.controller_option, self.plots = tuple(overrides), controller_option, plots
        self.plot_format, self.plot_dpi = plot_format, plot_dpi
        #: Why the figures were not drawn (a run without trace, or the plotting raised), None if they were.
        self.plots_skipped: str | None = None
        scenario = built.scenario
        self.metrics = run_metrics(built)
        self.travel = TravelWatch(built.plant)  # events, end_stop_contacts, saturation (gantry_twin.loop.events)
        self.part = part_watch(built)  # a part program's error (gantry_twin.gcode), None for other contours
        self.trace: TraceWriter | None = None
        self._made = [p for p in (self.out, *self.out.parents) if not p.exists()]  # deepest first
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            remove_stale_temporaries(self.out)  # an earlier run's, SIGKILLed before it could remove them
            if scenario.outputs.trace:
                self.trace = TraceWriter(self.out / TRACE_FILE, scenario.outputs.trace_stride)
            else:  # the trace writer's temporary file is the check; without one, try a file
                fh = tmp = None
                try:
                    with signals_held():
                        fh, tmp = temporary_file(self.out / SUMMARY_FILE)
                finally:
                    discard(fh, tmp)
        except BaseException:
            self.discard()
            raise

    def observers(self) -> list[Observer]:
        """The observers to run with: a stop signal a compile swallowed, the summary's metrics, the trace writer."""
        extra = [w for w in (self.part, self.trace) if w is not None]
        return [SwallowedInterrupt(), self.metrics, self.travel, *extra]

    def run(
        self,
        observers: Sequence[Observer] = (),
        hold_s: float | None = HOLD_S,
        chunk_s: float | None = None,
        keep_stopped: bool = False,
    ) -> RunOutcome:
        """Simulate the scenario holding ``hold_s`` of it in memory, writing it as it goes, and :meth:`finish`.
        ``chunk_s``: simulated seconds between two calls of the observers (None: the loop's default).

        A run stopped by a :class:`SimulationError` is written too (the trace
        up to the fault, ``status: failed``); any other error, or an
        interrupt, is raised (and the ``with`` block leaves nothing of the run).
        ``keep_stopped``: an interrupt (a stop signal) is raised only after the run is written as it stands, the
        trace up to the last chunk the observers saw and ``status: stopped`` (``serve``: what was served).
        """
        started = time.perf_counter()
        failure, fault = None, None
        seen = _LastChunk()
        try:
            trace: Trace | None = _simulate(self.built, [*self.observers(), *observers, seen], hold_s, chunk_s)
        except SimulationError as error:
            trace, fault = error.trace, error
            failure = Failure(error.time_s, error.step, f"{type(error).__name__}: {error}")
        except KeyboardInterrupt as interrupt:
            if not keep_stopped or seen.trace is None:
                self.discard()
                raise
            self._write_stopped(seen, interrupt, time.perf_counter() - started)
            raise
        except BaseException:
            self.discard()
            raise
        # A compile notice among the observers timed the loop's compile: the run's time is the rest.
        compile_s = sum(getattr(observer, "compile_s", 0.0) for observer in observers)
        wall_time_s = time.perf_counter() - started - compile_s
        return self.finish(trace, wall_time_s, failure, compile_s)._replace(error=fault)

    def _write_stopped(self, seen: _LastChunk, interrupt: KeyboardInterrupt, wall_time_s: float) -> None:
        """The run as far as its observers saw it, ``status: stopped`` (the interrupt's signal named)."""
        trace = seen.trace
        trace.filled = seen.stop  # what every observer saw (a chunk recorded after it was not handed over)
        for observer in self.observers():
            if not isinstance(observer, SwallowedInterrupt):  # the interrupt is being handled
                observer.on_end(trace)
        t_s = seen.stop * trace.sample_period_s
        what = f"stopped by {interrupt.args[0] if interrupt.args else 'SIGINT'} at t = {t_s:.4f} s (step {seen.stop})"
        self.finish(trace, wall_time_s, Failure(t_s, seen.stop, what, stopped=True))

    def finish(
        self, trace: Trace | None, wall_time_s: float, failure: Failure | None = None, compile_s: float = 0.0
    ) -> RunOutcome:
        """Write the run whose observers saw ``trace`` (the last piece; None if it stopped before its first
        sample): summary.json, the trace, scenario.yaml, run_info.json, and plots/ when asked for.
        ``wall_time_s``: the run without the loop's compile, ``compile_s`` (s, 0 when nothing compiled)."""
        built, out = self.built, self.out
        scenario = built.scenario
        data = _summary(
            built, trace, self.metrics, self.travel, failure, self.overrides, self.controller_option, self.part
        )
        written: list[str] = []
        try:
            (out / SUMMARY_FILE).unlink(missing_ok=True)  # from here the directory shows an incomplete run
            if self.trace is not None and trace is not None:
                self.trace.close()
                written.append(TRACE_FILE)
            atomic_write_text(out / SCENARIO_FILE, dump_yaml(scenario.resolved()))
            written.append(SCENARIO_FILE)
            atomic_write_text(out / RUN_INFO_FILE, json.dumps(_run_info(wall_time_s, compile_s), indent=2) + "\n")
            written.append(RUN_INFO_FILE)
            run_files = getattr(built.path, "run_files", None)  # a CNC's side of the run (docs/linuxcnc.md)
            for name, text in (run_files() if callable(run_files) else {}).items():
                atomic_write_text(out / name, text)
                written.append(name)
            if self.plots and self._plot(data, TRACE_FILE in written):
                written.append(PLOTS_DIR)
            for name in RUN_FILES:  # an earlier run's files that this run does not write
                if name not in written:
                    (out / name).unlink(missing_ok=True)
            if PLOTS_DIR not in written:
                remove_tree(out / PLOTS_DIR)
            atomic_write_text(out / SUMMARY_FILE, summary_json(data))
        except BaseException:
            for name in written:  # not a complete run: none of it stays
                if name == PLOTS_DIR:
                    remove_tree(out / name)
                else:
                    (out / name).unlink(missing_ok=True)
            self.discard()
            raise
        self.discard()  # a trace writer that saw no sample
        files = tuple(name for name in (*RUN_FILES, PLOTS_DIR) if name in written or name == SUMMARY_FILE)
        return RunOutcome(data, wall_time_s, tuple(f"{f}/" if f == PLOTS_DIR else f for f in files))

    def _plot(self, data: RunSummary, traced: bool) -> bool:
        """Draw the run's figures into plots/ (:func:`gantry_twin.outputs.plots.write_plots`); False, with
        :attr:`plots_skipped` saying why, when there is no trace or the drawing raised (the run is kept)."""
        from gantry_twin.outputs.plots import write_plots

        if not traced:
            self.plots_skipped = "no trace.parquet to draw from (outputs.trace: false)"
            return False
        try:
            plan = self.built.path if isinstance(self.built.path, ProgramPath) else None
            write_plots(self.out, self.out / PLOTS_DIR, data, self.plot_format, self.plot_dpi, plan)
        except Exception as exc:  # a figure is not worth the run
            self.plots_skipped = f"drawing them raised {type(exc).__name__}: {exc}"
            return False
        return True

    def discard(self) -> None:
        """Remove the temporary trace file, and the directories this writer made if they are empty."""
        if self.trace is not None:
            self.trace.discard()
        for path in self._made:
            try:
                path.rmdir()
            except OSError:
                break

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.discard()


class _LastChunk:
    """The last chunk every other observer has seen (an Observer, the last of a run's): its trace and end."""

    def __init__(self) -> None:
        self.trace: Trace | None = None
        self.stop = 0

    def on_start(self, run: object, trace: Trace) -> None:
        self.trace, self.stop = trace, trace.first

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        self.trace, self.stop = trace, stop

    def on_end(self, trace: Trace) -> None:
        pass


def run_and_write(
    out: Path, built: BuiltRun, observers: Sequence[Observer] = (), hold_s: float | None = HOLD_S
) -> RunOutcome:
    """Simulate a built scenario and write it into ``out`` as it goes (:meth:`RunWriter.run`).

    OSError before the run if ``out`` cannot be written.
    """
    with RunWriter(out, built) as writer:
        return writer.run(observers, hold_s)


def write_run(out: Path, built: BuiltRun, trace: Trace, wall_time_s: float, compile_s: float = 0.0) -> RunSummary:
    """Write a finished run's whole trace into ``out`` by the output contract; summary.json's content.
    ``wall_time_s``: the run without its loop's compile; ``compile_s``: the compile (0: none)."""
    with RunWriter(out, built) as writer:
        for observer in writer.observers():
            observer.on_chunk(trace, trace.first, trace.filled)
            observer.on_end(trace)
        return writer.finish(trace, wall_time_s, compile_s=compile_s).summary


def _summary(
    built: BuiltRun,
    trace: Trace | None,
    metrics: RunMetrics,
    travel: TravelWatch,
    failure: Failure | None = None,
    overrides: Sequence[str] = (),
    controller_option: str | None = None,
    part: PartErrorWatch | None = None,
) -> RunSummary:
    """summary.json's content from what a run's observers gathered (``trace``: its last piece, or None)."""
    scenario = built.scenario
    health = built.monitor.report() if built.monitor is not None else None
    steps = trace.filled if trace is not None else 0
    period = trace.sample_period_s if trace is not None else built.plant.timestep_s
    return run_summary(
        scenario,
        scenario.controller.name,
        period,
        steps,
        metrics,
        health,
        failure,
        overrides,
        controller_option,
        travel.summary(),
        part.summary() if part is not None else None,
    )


def summarise(built: BuiltRun, trace: Trace) -> RunSummary:
    """summary.json's content for a finished run's whole trace, as :class:`RunWriter` writes it (nothing written)."""
    metrics = run_metrics(built)
    travel = TravelWatch(built.plant)
    part = part_watch(built)
    for observer in (metrics, travel, part):
        if observer is not None:
            observer.on_chunk(trace, trace.first, trace.filled)
    return _summary(built, trace, metrics, travel, part=part)


def run_metrics(built: BuiltRun) -> RunMetrics:
    """What summary.json judges a run by: its scenario's windows; a part program's rapid (G0) moves left out of
    the contour figures (the part error leaves them out too; docs/gcode.md)."""
    confidence = estimate_confidence(built)
    if isinstance(built.path, ProgramPath):
        return RunMetrics.for_program(built.scenario, built.path.rapid_spans(), confidence)
    return RunMetrics.for_scenario(built.scenario, confidence)


def part_watch(built: BuiltRun) -> PartErrorWatch | None:
    """The part-error observer of a run of a G-code program (its contour is a planned program)."""
    return PartErrorWatch(built.path) if isinstance(built.path, ProgramPath) else None


class ScenarioRun(NamedTuple):
    """What :func:`run_scenario` gives: summary.json's content (typed) and the whole trace."""

    summary: RunSummary
    trace: Trace


def run_scenario(
    scenario: str | Path,
    overrides: Sequence[str] = (),
    controller: str | None = None,
    out: str | Path | None = None,
) -> ScenarioRun:
    """Run a scenario file (or a shipped scenario's name) from Python, as ``gantry-twin run`` does.

    ``overrides`` are ``--set`` strings (``"duration_s=5"``), ``controller``
    is ``--controller``; with ``out`` the run's directory is written there
    (summary.json, scenario.yaml, trace.parquet, run_info.json). Raises
    ScenarioError (one line) for bad input, SimulationError for a fault.
    """
    from gantry_twin.loop.compiling import compile_timer
    from gantry_twin.scenario import build, load_scenario, resolve_scenario

    path = resolve_scenario(str(scenario))
    built = build(load_scenario(path, list(overrides), controller), str(path))
    timer = compile_timer(built.controller)  # run_info.json's compile_s, as gantry-twin run's notice times it
    started = time.perf_counter()
    trace = execute(built, [timer])
    if out is not None:
        wall_time_s = time.perf_counter() - started - timer.compile_s
        return ScenarioRun(write_run(Path(out), built, trace, wall_time_s, timer.compile_s), trace)
    return ScenarioRun(summarise(built, trace), trace)


def package_version() -> str:
    """The installed gantry-twin's version ("unknown" when run from a source tree that is not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("gantry-twin")
    except PackageNotFoundError:
        return "unknown"


def _run_info(wall_time_s: float, compile_s: float = 0.0) -> dict[str, Any]:
    """What differs between two runs of the same scenario (kept out of summary.json): the run's wall time s
    without the loop's compile, and the compile's s (0 when the loop came from the cache)."""
    import mujoco

    return {
        "wall_time_s": wall_time_s,
        "compile_s": compile_s,
        "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "gantry_twin": package_version(),
        "mujoco": mujoco.__version__,
        "python": platform.python_version(),
        "machine": platform.machine(),
    }
