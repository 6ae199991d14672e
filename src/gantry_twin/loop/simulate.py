"""The 0.2 ms loop: measure -> control -> disturb -> mj_step -> record.

The controller runs once per sample (Ts = the plant's ``timestep_s``, 0.2 ms);
the plant advances ``plant.substeps`` physics steps per sample (one for the
Coulomb friction, more for LuGre: docs/friction.md). The command is computed
from that sample's measurement and held over the sample (zero-order hold, as
the DS1103's DAC does). The disturbance actuators
are driven from the scenario's timeline; the controller never sees them.

The loop records into a :class:`Trace` preallocated for the whole run and
hands it to observers (progress bars, live telemetry, pacing, a trace
writer) after every chunk of ``chunk_s`` simulated seconds. Observers only
read the trace: nothing they do changes the simulation. A long run can be
held in pieces of ``hold_s`` seconds instead (the reference, the
disturbance and the trace computed piece by piece, the same numbers):
memory then stays bounded and the observers are where the trace goes.

A fault (a non-finite measurement or command, an exception in the
controller) stops the run with a :class:`SimulationError` that names the
time and the sample; the samples before it are recorded, shown to the
observers and kept in the error's ``trace``.

One sample is written once, in :func:`run_chunk`: plant changes
(:mod:`gantry_twin.plant.faults`), the encoder (:mod:`gantry_twin.plant.sensing`), the
controller, clipping and recording, MuJoCo's step. Two backends run it
(docs/performance.md):

* ``compiled``: for a controller that offers a compiled step (the plug-in
  protocol of :mod:`gantry_twin.controllers.base`; the built-ins do), one
  numba kernel per chunk, specialised to that controller's step, which
  calls MuJoCo's C ``mj_step`` directly (through the shared library the
  mujoco wheel ships), with no Python in the 0.2 ms loop. It leaves the
  controller object in the state the reference run leaves.
* ``reference``: the same chunk function run by the Python interpreter with
  every kernel uncompiled, calling ``controller.update()`` every sample and
  ``mujoco.mj_step``; any controller runs this way.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Literal, TypeVar

import mujoco
import numpy as np

from gantry_twin.controllers.base import (
    CompiledStep,
    Controller,
    Measurement,
    ReferenceSample,
    RunContext,
    compiled_step_of,
)
from gantry_twin.loop.sample import (
    STATUS_BAD_COMMAND,
    STATUS_BAD_MEASUREMENT,
    PlantIO,
    Recording,
    SampleWork,
    chunk_kernel,
    mj_step,
    needs_reference_counting,
    record_and_step,
    run_chunk,
)
from gantry_twin.loop.trace import Observer, RunInfo, SimulationError, Trace
from gantry_twin.loop.worker import WorkerLoop, isolation_of, shared_full
from gantry_twin.numerics.jit import is_cached, specialise
from gantry_twin.numerics.jit import reference as uncompiled
from gantry_twin.paths.contours import Contour, Reference, ReferenceEnded, ReferenceStream, TimingLaw, contour_error
from gantry_twin.paths.taskframe import normal_errors
from gantry_twin.plant.faults import (
    ChangeSchedule,
    PlantChanges,
    change_schedule,
    sensor_glitches,
)
from gantry_twin.plant.model import Plant, operating_point_m
from gantry_twin.plant.sensing import Encoder, SensingConfig, encoder_measure

T = TypeVar("T")

#: A disturbance timeline: times (N,) s -> input disturbance (N, 2) volts.
Disturbance = Callable[[np.ndarray], np.ndarray]


def _finish_chunk(trace: Trace, ref: Reference, path: Contour, start: int, stop: int) -> None:
    """Derived errors for samples [start, stop) (``ref``: the reference of the trace's samples): e, eps_n, eps_c."""
    rows = trace.rows(start, stop)
    normal_errors(ref.alpha[rows], trace.q_m[rows], ref.q_d[rows], trace.e_m[rows], trace.eps_n_m[rows])
    trace.eps_c_m[rows], _ = contour_error(path, trace.q_m[rows], ref.phi[rows])
    trace.filled = stop


Backend = Literal["auto", "compiled", "reference"]


def loop_needs_compiling(controller: Controller) -> bool:
    """True if simulate() with this controller will first compile its loop (once per machine and source version)."""
    compiled = compiled_step_of(controller)
    if compiled is None or not compiled_available():
        return False
    return not any(is_cached(chunk_kernel(compiled, nrt)) for nrt in (False, True))


def _chunk_for(compiled: CompiledStep) -> Callable[..., tuple[int, int]]:
    """The chunk kernel to call: without reference counting, unless only the one with it is cached (a step that
    allocates: the one without fails to compile, :func:`gantry_twin.loop.sample.needs_reference_counting`)."""
    plain = chunk_kernel(compiled)
    counted = chunk_kernel(compiled, nrt=True)
    return counted if is_cached(counted) and not is_cached(plain) else plain


def compiled_available() -> bool:
    """True if MuJoCo's mj_step could be made callable from compiled code."""
    return mj_step is not None


def sample_count(duration_s: float, timestep_s: float) -> int:
    """How many samples a run of ``duration_s`` has."""
    return int(round(duration_s / timestep_s))


def simulate(
    plant: Plant,
    path: Contour,
    timing: TimingLaw,
    controller: Controller,
    duration_s: float,
    sensing: SensingConfig | None = None,
    disturbance: Disturbance | None = None,
    observers: Sequence[Observer] = (),
    chunk_s: float = 0.1,
    controller_name: str | None = None,
    backend: Backend = "auto",
    changes: PlantChanges | None = None,
    hold_s: float | None = None,
) -> Trace:
    """Run the closed loop for ``duration_s`` seconds and return the trace.

    The plant starts at q_d(0) moving at q_d'(0): for an ``on_path`` timing
    law that is the paper's "already running" start; for ``rest``, standstill.
    backend: ``auto`` (compiled for a controller that offers a compiled step
    when MuJoCo's library is found, else reference), ``compiled`` or
    ``reference``; both give the same trace (tests/test_backends.py).
    changes: faults applied to the plant and the sensor during the run
    (:mod:`gantry_twin.plant.faults`), never shown to the controller; the trace
    then records the true theta over time (``true_theta_t``). A payload
    change needs a plant built with ``payload_body=True``. The model's
    damping, friction and masses are restored after the run.
    A live contour (one whose reference raises :class:`ReferenceEnded`) ends
    the run before ``duration_s``: the trace returned is the last piece held.
    hold_s: hold at most this much of the run in memory (rounded up to whole
    chunks): the run goes piece by piece, the observers see every chunk
    while its piece is held (``RunInfo.reference`` is None, ``Trace.first``
    says where a piece starts) and the trace returned is the last piece. The
    numbers are those of a whole run; ``disturbance`` must then give each
    time's value from that time alone. None: the whole run is held.

    Raises :class:`SimulationError` (with the time, the sample and the trace
    of the samples before it) when a measurement or command is not finite
    or the controller raises; the observers have seen those samples and
    their ``on_end``.
    """
    if backend not in ("auto", "compiled", "reference"):
        raise ValueError(f"backend must be 'auto', 'compiled' or 'reference', got {backend!r}")
    compiled_step = compiled_step_of(controller)
    if backend == "compiled" and compiled_step is None:
        raise ValueError(
            f"backend 'compiled' runs only controllers that offer a compiled step "
            f"(gantry_twin.controllers.base); {type(controller).__name__} does not"
        )
    if backend == "compiled" and not compiled_available():
        raise RuntimeError("backend 'compiled': MuJoCo's shared library was not found next to the mujoco module")
    compiled = backend == "compiled" or (backend == "auto" and compiled_step is not None and compiled_available())

    sensing = sensing or SensingConfig()
    ts = plant.timestep_s
    n = sample_count(duration_s, ts)
    if n < 2:
        raise ValueError(f"duration_s must hold at least two samples of {ts} s, got {duration_s}")
    chunk = max(1, int(round(chunk_s / ts)))
    piece = n if hold_s is None else min(n, chunk * max(1, math.ceil(hold_s / ts / chunk)))
    moving = changes is not None and not changes.empty
    schedule = change_schedule(plant, changes, np.arange(n) * ts if moving else np.zeros(0))
    references = ReferenceStream(path, timing)
    model = plant.model
    saved = _changed_fields(model)
    operating = operating_point_m(path)
    true_theta = plant.true_parameters(operating)
    loop: _Loop | None = None
    try:
        for first in range(0, n, piece):
            t = np.arange(first, min(n, first + piece)) * ts
            try:
                ref = references.next(t)
            except ReferenceEnded:  # a live reference's source ended: the run ends with the samples before t
                if loop is None:
                    raise
                break
            dist = np.zeros((t.size, 2)) if disturbance is None else np.asarray(disturbance(t), dtype=float)
            if dist.shape != (t.size, 2):
                raise ValueError(f"disturbance must give shape ({t.size}, 2) volts, got {dist.shape}")
            # A worker's first piece is recorded in memory it shares with this process: no copy of it comes back.
            full = shared_full if loop is None and isolation_of(controller) is not None else np.full
            trace = Trace.allocate(ref, np.ascontiguousarray(dist), true_theta, first, ts, full)
            if moving:
                trace.true_theta_t = _as_before(model, saved, changes.true_parameters_over_time, plant, t, operating)
                if first == 0:
                    true_theta = trace.true_theta_t[0].copy()
                trace.true_theta = true_theta
            if loop is None:
                plant.reset(ref.q_d[0], ref.dq_d[0])
                encoder = Encoder(sensing, ts)
                encoder.reset(plant.q_m, plant.dq_m_s)
                name = controller_name or type(controller).__name__
                info = RunInfo(plant, path, timing, ref if piece == n else None, duration_s, name, n)
                for observer in observers:
                    observer.on_start(info, trace)
                rows = np.ascontiguousarray(ref.packed())
                loop = _make_loop(
                    plant, encoder, controller, trace, rows, schedule, compiled_step if compiled else None
                )
            else:
                rows = np.ascontiguousarray(ref.packed())
            loop.hold(trace, rows)
            for start in range(first, first + t.size, chunk):
                stop, error = loop.run(start, min(first + t.size, start + chunk))
                if stop > start:
                    _finish_chunk(trace, ref, path, start, stop)
                    for observer in observers:
                        observer.on_chunk(trace, start, stop)
                if error is not None:
                    for observer in observers:
                        observer.on_end(trace)
                    error.trace = trace
                    raise error
        for observer in observers:
            observer.on_end(trace)
    except BaseException:
        _restore(model, saved)
        if isinstance(loop, WorkerLoop):
            loop.stop()  # the worker, and what the controller holds in it, gone at once
        _close(controller if loop is None else loop, None)  # the run's own error (or the interrupt) is what is raised
        raise
    _restore(model, saved)
    _close(loop, trace)
    return trace


def _make_loop(
    plant: Plant,
    encoder: Encoder,
    controller: Controller,
    trace: Trace,
    rows: np.ndarray,
    changes: ChangeSchedule,
    compiled: CompiledStep | None,
) -> _Loop | WorkerLoop:
    """The run's loop: in this process, or in a worker process when the controller hosts foreign code
    (:mod:`gantry_twin.loop.worker`; the chunk kernel loaded here first, on an empty chunk)."""
    isolation = isolation_of(controller)
    if isolation is None:
        return _Loop(plant, encoder, controller, trace, changes, compiled)

    def warm() -> None:
        if compiled is None or isolation.placeholders is None:
            return
        function = _chunk_for(compiled)
        if getattr(function, "signatures", None):
            return  # loaded already (one signature serves every FMU: the addresses are arguments)
        recording = Recording(
            trace.first,
            trace.t_s,
            rows,
            trace.disturbance_v,
            trace.q_m,
            trace.q_meas_m,
            trace.u_v,
            np.zeros(0),
            np.zeros(0, dtype=np.int64),
        )
        sample = SampleWork(*(np.zeros(2) for _ in range(5)), np.zeros(compiled.log_size))
        arguments = (plant_io(plant), encoder.state, recording, sample, changes, *isolation.placeholders)
        try:
            function(0, 0, *arguments)
        except Exception as exc:
            if not needs_reference_counting(exc):
                raise
            chunk_kernel(compiled, nrt=True)(0, 0, *arguments)

    layout = compiled.layout if compiled is not None else ()
    return WorkerLoop(
        lambda: _Loop(plant, encoder, controller, trace, changes, compiled), isolation, trace, rows, warm, layout
    )


def _close(loop: _Loop | WorkerLoop | Controller | None, trace: Trace | None) -> None:
    """The controller's optional ``close()`` (it releases what ``reset`` took: an FMU's instance, its files),
    through the loop that runs it. After a run that went well (``trace``) an exception from it fails the run at its
    last sample; after a run that failed, the run's own error stands."""
    close = getattr(loop, "close", None)
    if not callable(close):
        return
    try:
        close()
    except Exception as exc:
        if trace is None:
            return
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        error = _stopped_at(trace, trace.first + trace.t_s.size - 1, "closing the controller failed", f": {why}")
        error.trace = trace
        raise error from exc


def _changed_fields(model: mujoco.MjModel) -> tuple[np.ndarray, ...]:
    """Copies of the model fields plant changes write (damping, friction loss, masses, LuGre's levels)."""
    return (
        model.dof_damping.copy(),
        model.dof_frictionloss.copy(),
        model.body_mass.copy(),
        model.actuator_biasprm.copy(),
    )


def _restore(model: mujoco.MjModel, saved: tuple[np.ndarray, ...]) -> None:
    """Write back the fields :func:`_changed_fields` copied."""
    model.dof_damping[:], model.dof_frictionloss[:], model.body_mass[:], model.actuator_biasprm[:] = saved


def _as_before(model: mujoco.MjModel, saved: tuple[np.ndarray, ...], function: Callable[..., T], *args: object) -> T:
    """``function(*args)`` computed on the model as it was before the run (``saved``: :func:`_changed_fields`;
    the loop writes the scheduled values into it)."""
    during = _changed_fields(model)
    _restore(model, saved)
    try:
        return function(*args)
    finally:
        _restore(model, during)


def _stopped_at(trace: Trace, k: int, what: str, detail: str = "") -> SimulationError:
    """The error that stops a run at sample k of the trace: "<what> at t = ... s (step k)<detail>"."""
    t_s = float(trace.t_s[trace.rows(k, k + 1)][0])
    return SimulationError(f"{what} at t = {t_s:.4f} s (step {k}){detail}", t_s, k)


class _Loop:
    """One run's chunk function and its arguments: compiled (a compiled step) or the reference loop."""

    def __init__(
        self,
        plant: Plant,
        encoder: Encoder,
        controller: Controller,
        trace: Trace,
        changes: ChangeSchedule,
        compiled: CompiledStep | None,
    ) -> None:
        u_max = np.ascontiguousarray(plant.ctrl_range_v[:, 1], dtype=float)
        # The first measurement, for the controller's RunContext; the loop measures it again from here.
        sensor = encoder.state._replace(previous_m=encoder.state.previous_m.copy())
        position, velocity = np.zeros(2), np.zeros(2)
        glitches = uncompiled(sensor_glitches)(changes, 0)
        if not uncompiled(encoder_measure)(
            encoder.state, plant.q_m.copy(), plant.dq_m_s.copy(), *glitches, position, velocity
        ):
            raise _stopped_at(trace, 0, "non-finite measurement", f": q = {position}, q' = {velocity}")
        t0 = float(trace.t_s[0])
        controller.reset(RunContext(plant.timestep_s, u_max.copy(), Measurement(t0, position, velocity)))

        self.plant = plant_io(plant, u_max)
        self.encoder, self.changes, self.compiled, self.controller = sensor, changes, compiled, controller
        if compiled is not None:
            self.params, self.state = controller.kernel_arguments()
            self.function = _chunk_for(compiled)
            log_row = np.zeros(compiled.log_size)
        else:
            self.params, self.state = None, None
            log_row = np.zeros(0)
            self.function = _python_chunk(plant, controller, self)
        self.sample = SampleWork(np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2), log_row)

    def close(self) -> None:
        """The controller's optional ``close()``."""
        close = getattr(self.controller, "close", None)
        if callable(close):
            close()

    def hold(self, trace: Trace, rows: np.ndarray) -> None:
        """Record into ``trace`` from now on; rows: the packed reference of its samples."""
        self.trace = trace
        if self.compiled is not None:
            log = trace.allocate_log(self.compiled.layout)
            sizes = np.array([int(np.prod(shape)) for _, shape in self.compiled.layout], dtype=np.int64)
        else:
            log, sizes = np.zeros(0), np.zeros(0, dtype=np.int64)
        self.recording = Recording(
            trace.first, trace.t_s, rows, trace.disturbance_v, trace.q_m, trace.q_meas_m, trace.u_v, log, sizes
        )

    def run(self, start: int, stop: int) -> tuple[int, SimulationError | None]:
        """Samples [start, stop): (stop, None), or (k, the error) if the run cannot go on at sample k."""
        arguments = (self.plant, self.encoder, self.recording, self.sample, self.changes, self.params, self.state)
        try:
            try:
                status, k = self.function(start, stop, *arguments)
            except Exception as exc:
                counted = None if self.compiled is None else chunk_kernel(self.compiled, nrt=True)
                if counted is None or self.function is counted or not needs_reference_counting(exc):
                    raise
                self.function = counted  # the step allocates: compile it with reference counting
                status, k = self.function(start, stop, *arguments)
        except (Exception, SystemExit) as exc:  # the controller's step raised (sys.exit() too): the first sample
            # not recorded is where
            recorded = ~np.isnan(self.trace.q_m[self.trace.rows(start, stop), 0])
            k = start + int(np.argmin(recorded)) if not recorded.all() else stop
            text = str(exc).splitlines()[0] if str(exc) else ""
            if isinstance(exc, SimulationError):
                error = _stopped_at(self.trace, min(k, stop - 1), text)
            else:
                what = f"the controller raised {type(exc).__name__}"
                error = _stopped_at(self.trace, min(k, stop - 1), what, f": {text}" if text else "")
            error.__cause__ = exc
            return min(k, stop - 1), error
        if status == STATUS_BAD_MEASUREMENT:
            q, dq = self.sample.position.copy(), self.sample.velocity.copy()
            return k, _stopped_at(self.trace, k, "non-finite measurement", f": q = {q}, q' = {dq}")
        if status == STATUS_BAD_COMMAND:
            fault = getattr(self.controller, "fault", None)
            why = fault() if callable(fault) else None  # a controller that wraps outside code says what failed
            if why:
                return k, _stopped_at(self.trace, k, "the controller failed", f": {why}")
            command = self.sample.command.copy()
            return k, _stopped_at(self.trace, k, f"controller returned {command!r}", "; expected 2 finite volts")
        return stop, None


def plant_io(plant: Plant, u_max_v: np.ndarray | None = None) -> PlantIO:
    """What the loop kernels touch of ``plant`` (:class:`PlantIO`); u_max_v: the DAC limits (2,) V, the control
    motors' ranges by default."""
    data = plant.data
    u_max = np.ascontiguousarray(plant.ctrl_range_v[:, 1] if u_max_v is None else u_max_v, dtype=float)
    return PlantIO(
        plant.model._address,
        data._address,
        data.qpos,
        data.qvel,
        data.ctrl,
        *(
            np.ascontiguousarray(i, dtype=np.int64)
            for i in (plant.qpos_index, plant.dof_index, plant.motor_index, plant.disturbance_index)
        ),
        u_max,
        plant.substeps,
        np.ascontiguousarray(plant.input_table()),
        int(plant.amplifier.delay_samples),
        float(plant.amplifier.current_gain(plant.timestep_s)),
        plant.amplifier.state(),
    )


def reference_record_and_step(plant: Plant) -> Callable[..., bool]:
    """:func:`gantry_twin.loop.sample.record_and_step` run by the interpreter on ``plant``, ``mujoco.mj_step`` as
    its physics step (the reference backend's)."""

    def python_mj_step(model_address: int, data_address: int) -> None:
        mujoco.mj_step(plant.model, plant.data)  # called plant.substeps times per sample, as the compiled loop

    return specialise(record_and_step, "python", {"mj_step": python_mj_step}, compiled=False)


def _python_chunk(plant: Plant, controller: Controller, loop: _Loop) -> Callable[..., tuple[int, int]]:
    """The chunk function run by the interpreter: ``update()`` as the step, ``state_for_logging`` as the log."""

    def step(
        params: None, state: None, t_s: float, q_m: np.ndarray, dq_m_s: np.ndarray, ref: np.ndarray, u_v: np.ndarray
    ) -> None:
        measurement = Measurement(float(t_s), q_m.copy(), dq_m_s.copy())
        command = np.asarray(controller.update(measurement, ReferenceSample.from_row(ref)), dtype=float)
        if command.shape != (2,):
            raise SimulationError(f"controller returned {command!r}, not 2 volts")
        u_v[:] = command

    def record_log(recording: Recording, j: int, row: np.ndarray) -> None:
        loop.trace.record_state(j, controller.state_for_logging())

    bindings = {
        "controller_step": step,
        "controller_log": lambda params, state, out: None,
        "record_log": record_log,
        "record_and_step": reference_record_and_step(plant),
    }
    return specialise(run_chunk, "python", bindings, compiled=False)
