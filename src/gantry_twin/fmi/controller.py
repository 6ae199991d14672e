"""A controller FMU as a controller of the loop: ``controller: {name: fmu, options: {fmu: PATH, ...}}``.

Every sample the step (:func:`fmu_step`) sets the FMU's bound inputs (the measurement and the reference sample,
SI), calls ``fmi2DoStep`` from the sample's time over the sample period and reads the two commands (volts),
which the loop clips and holds over the sample as every controller's. A native FMU (a shared library, what
Simulink and Modelica tools export) runs in the compiled loop: the step calls the library's C entry points by
address (:mod:`gantry_twin.fmi.calls`), no Python per sample. An FMU built with pythonfmu runs its Python class
inside its library: it runs on the Python loop (:class:`PythonFmuController`), the same step uncompiled.

A call that returns fmi2Discard, fmi2Error, fmi2Fatal or fmi2Pending ends the run at that sample: the step
writes NaN commands, the loop stops as for any non-finite command, and :meth:`FmuController.fault` names the
FMU file, the call, its status and the FMU's last log message. ``close()`` (after the run) terminates the FMU and
removes its unpacked files (docs/fmi.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from gantry_twin.controllers.base import (
    REF_DDQ,
    REF_DQ,
    REF_Q,
    CompiledStep,
    Controller,
    LogLayout,
    Measurement,
    ReferenceSample,
    RunContext,
    compiled_step_of,
)
from gantry_twin.fmi.calls import FMI2_WARNING, do_step, get_real, set_real
from gantry_twin.fmi.description import INPUT_SIGNALS, ControllerFmu, read_controller
from gantry_twin.fmi.instance import Instance, trial_start
from gantry_twin.loop.process import CALL_TIMEOUT_S, MEMORY_LIMIT_BYTES
from gantry_twin.loop.worker import (
    PROGRESS_CALL,
    PROGRESS_SAMPLES,
    PROGRESS_T_S,
    Isolation,
    shared_progress,
)
from gantry_twin.numerics.jit import kernel
from gantry_twin.numerics.jit import reference as uncompiled

#: A logged FMU variable's key in the trace (and its trace.parquet column): ``fmu_<name>``, apart from the
#: trace's own columns (an FMU's ``u_x_v`` is ``fmu_u_x_v``).
LOG_PREFIX = "fmu_"
#: Which call failed (FmuState.failed[1]), and which the FMU is in (its progress row, gantry_twin.loop.worker).
CALLS = (
    "",
    "fmi2SetReal",
    "fmi2DoStep",
    "fmi2GetReal",
    "its start (fmi2Instantiate to initialisation)",
    "fmi2Terminate",
)
CALL_SET_REAL, CALL_DO_STEP, CALL_GET_REAL, CALL_START, CALL_TERMINATE = 1, 2, 3, 4, 5
#: The allowed range of each limit option: call_timeout_s (s), memory_limit_mb (MiB).
LIMITS = {"call_timeout_s": (0.01, 86400.0), "memory_limit_mb": (64.0, 1048576.0)}


class FmuParams(NamedTuple):
    """The addresses of fmi2SetReal, fmi2DoStep, fmi2GetReal and of the component (integers, one run's); the value
    references (uint32) of the bound inputs, their signals (index into the signal row :data:`INPUT_SIGNALS`), the
    two outputs and the logged variables; the sample period s (the communication step)."""

    set_real: int
    do_step: int
    get_real: int
    component: int
    input_vr: np.ndarray
    input_signal: np.ndarray
    output_vr: np.ndarray
    log_vr: np.ndarray
    step_s: float


class FmuState(NamedTuple):
    """signals (11,): the sample's signal row; inputs (n,): the bound inputs' values; failed (2,) int64: the status
    of the call that failed and which (:data:`CALLS`), zeros while none has; progress (3,): the call the FMU is in,
    the sample's time s and the samples started (:func:`gantry_twin.loop.worker.shared_progress`, shared with the
    process that watches the loop's worker)."""

    signals: np.ndarray
    inputs: np.ndarray
    failed: np.ndarray
    progress: np.ndarray


@kernel(inline=True, internal=True, nrt=False)
def _entering(state, call):
    """The FMU is entering ``call`` (:data:`CALLS`): written where the watching process reads it."""
    state.progress[PROGRESS_CALL] = call


@kernel(inline=True, internal=True, nrt=False)
def _fail(state, call, status, u_v):
    """Record the failed call and make the command non-finite: the loop stops at this sample."""
    state.failed[0] = status
    state.failed[1] = call
    u_v[0] = np.nan
    u_v[1] = np.nan


@kernel(nrt=False)
def fmu_step(params, state, t_s, q_m, dq_m_s, ref, u_v):
    """Set the bound inputs, fmi2DoStep(t_s, Ts), read u_x_v, u_y_v into u_v (2,) volts; NaN if a call failed."""
    s = state.signals
    s[0] = t_s
    state.progress[PROGRESS_T_S] = t_s
    state.progress[PROGRESS_SAMPLES] += 1.0
    for i in range(2):
        s[1 + i] = q_m[i]
        s[3 + i] = dq_m_s[i]
        s[5 + i] = ref[REF_Q + i]
        s[7 + i] = ref[REF_DQ + i]
        s[9 + i] = ref[REF_DDQ + i]
    n = params.input_vr.shape[0]
    for j in range(n):
        state.inputs[j] = s[params.input_signal[j]]
    if n > 0:
        _entering(state, CALL_SET_REAL)
        status = set_real(params.set_real, params.component, params.input_vr, n, state.inputs)
        if status > FMI2_WARNING:
            _fail(state, CALL_SET_REAL, status, u_v)
            return
    _entering(state, CALL_DO_STEP)
    status = do_step(params.do_step, params.component, t_s, params.step_s)
    if status > FMI2_WARNING:
        _fail(state, CALL_DO_STEP, status, u_v)
        return
    _entering(state, CALL_GET_REAL)
    status = get_real(params.get_real, params.component, params.output_vr, 2, u_v)
    if status > FMI2_WARNING:
        _fail(state, CALL_GET_REAL, status, u_v)


@kernel(nrt=False)
def fmu_log(params, state, out):
    """The logged variables' values after the sample's step into ``out`` (NaN if fmi2GetReal fails)."""
    m = params.log_vr.shape[0]
    if m > 0:
        _entering(state, CALL_GET_REAL)
        status = get_real(params.get_real, params.component, params.log_vr, m, out)
        if status > FMI2_WARNING:
            for i in range(m):
                out[i] = np.nan


class FmuStep:
    """A controller FMU through the plug-in protocol, on the Python loop (:func:`fmu_step` uncompiled).

    Its ``isolation`` asks the loop to run it in a worker process (:mod:`gantry_twin.loop.worker`): a crash, an
    ``exit``, a call that exceeds ``call_timeout_s`` s or a worker past ``memory_limit_bytes`` of resident memory
    ends the run as failed, the trace up to the last finished chunk kept (docs/fmi.md).

    The FMU is read and checked when made (:func:`gantry_twin.fmi.description.read_controller`), unpacked and
    instantiated by :meth:`reset`, ended by :meth:`close`.
    """

    def __init__(
        self, fmu: ControllerFmu, call_timeout_s: float = CALL_TIMEOUT_S, memory_limit_bytes: int = MEMORY_LIMIT_BYTES
    ) -> None:
        self.fmu = fmu
        self.instance: Instance | None = None
        self._params: FmuParams | None = None
        self._progress = shared_progress()
        self._state = self._fresh_state()
        #: The run goes in a worker process that the command's watches (gantry_twin.loop.worker; docs/fmi.md).
        self.isolation = Isolation(
            fmu.path.name, call_timeout_s, memory_limit_bytes, self._progress, CALLS, self._placeholders()
        )

    def __setstate__(self, state: dict) -> None:
        """A copy (pickled, deep-copied) gets a progress row of its own in shared memory: a copied array would be
        private, and the process watching the loop's worker would not see the worker's progress."""
        self.__dict__.update(state)
        self._progress = shared_progress()
        self._state = self._state._replace(progress=self._progress)
        placeholders = self._placeholders()
        self.isolation = self.isolation._replace(progress=self._progress, placeholders=placeholders)

    def _fresh_state(self) -> FmuState:
        f = self.fmu
        return FmuState(
            np.zeros(len(INPUT_SIGNALS)), np.zeros(len(f.inputs)), np.zeros(2, dtype=np.int64), self._progress
        )

    def _placeholders(self) -> tuple[FmuParams, FmuState] | None:
        """(params, state) of the compiled step's types, no FMU behind them: the chunk kernel is loaded with them
        before the worker starts (on an empty chunk, which calls nothing)."""
        if compiled_step_of(self) is None:
            return None
        none = np.zeros(0, dtype=np.uint32)
        return FmuParams(0, 0, 0, 0, none, np.zeros(0, dtype=np.int64), none, none, 0.0), self._fresh_state()

    def reset(self, context: RunContext) -> None:
        """A fresh instance at the first measurement's time, the communication step the sample period."""
        self.close()
        self._progress[PROGRESS_CALL] = CALL_START
        self.instance = Instance(self.fmu, float(context.initial_measurement.t_s))
        f = self.fmu
        self._params = FmuParams(
            *self.instance.addresses,
            np.array([v.value_reference for v in f.inputs], dtype=np.uint32),
            np.array([INPUT_SIGNALS.index(v.signal) for v in f.inputs], dtype=np.int64),
            np.array([v.value_reference for v in f.outputs], dtype=np.uint32),
            np.array([v.value_reference for v in f.logged], dtype=np.uint32),
            float(context.sample_period_s),
        )
        self._state = self._fresh_state()

    def kernel_arguments(self) -> tuple[FmuParams, FmuState]:
        """(params, state) of :func:`fmu_step` (after :meth:`reset`)."""
        if self._params is None:
            raise RuntimeError("FmuController.kernel_arguments: call reset() first (it instantiates the FMU)")
        return self._params, self._state

    def update(self, measurement: Measurement, reference: ReferenceSample) -> np.ndarray:
        params, state = self.kernel_arguments()
        u = np.zeros(2)
        uncompiled(fmu_step)(
            params,
            state,
            float(measurement.t_s),
            np.ascontiguousarray(measurement.q_m, dtype=float),
            np.ascontiguousarray(measurement.dq_m_s, dtype=float),
            reference.row(),
            u,
        )
        return u

    def state_for_logging(self) -> dict[str, np.ndarray]:
        if not self.fmu.logged:
            return {}
        params, state = self.kernel_arguments()
        out = np.zeros(len(self.fmu.logged))
        uncompiled(fmu_log)(params, state, out)
        return {LOG_PREFIX + v.name: out[i : i + 1].copy() for i, v in enumerate(self.fmu.logged)}

    def fault(self) -> str | None:
        """Why the last command is not finite: the FMU call that failed (None if none did)."""
        status, call = (int(x) for x in self._state.failed)
        if not call or self.instance is None:
            return None
        return self.instance.why(CALLS[call], status)

    def close(self) -> None:
        """End the run's instance: fmi2Terminate, fmi2FreeInstance, its unpacked files removed (FmuError if
        fmi2Terminate fails). Nothing to do before :meth:`reset` or after a close."""
        instance, self.instance = self.instance, None
        self._params = None
        if instance is not None:
            self._progress[PROGRESS_CALL] = CALL_TERMINATE
            instance.failed_status = max(instance.failed_status, int(self._state.failed[0]))  # what FMI then forbids
            instance.close()


class FmuController(FmuStep):
    """A native controller FMU: its compiled step is :func:`fmu_step`, in the compiled loop."""

    compiled = CompiledStep(fmu_step, fmu_log, ())


class PythonFmuController(FmuStep):
    """A controller FMU that needs Python (built with pythonfmu): no compiled step, the Python loop runs it."""


_LOGGING_CLASSES: dict[LogLayout, type[FmuController]] = {}


def _with_log_layout(layout: LogLayout) -> type[FmuController]:
    """FmuController with the log layout of its logged variables (the loop reads it from the class; one compiled
    loop for all: the kernels are the same)."""
    found = _LOGGING_CLASSES.get(layout)
    if found is None:
        found = type("FmuController", (FmuController,), {"compiled": CompiledStep(fmu_step, fmu_log, layout)})
        found.__module__ = __name__
        _LOGGING_CLASSES[layout] = found
    return found


def fmu_controller(
    fmu: Path | None = None,
    variables: dict[str, str] | None = None,
    parameters: dict[str, float] | None = None,
    log_variables: tuple[str, ...] = (),
    call_timeout_s: float = CALL_TIMEOUT_S,
    memory_limit_mb: float = MEMORY_LIMIT_BYTES / 2**20,
) -> Controller:
    """The controller of a co-simulation FMU (the factory of ``controller: {name: fmu}``; docs/fmi.md).

    fmu: the .fmu file (a scenario's is relative to the scenario file). variables: {FMU variable: signal} for
    variables not named as the convention's signals. parameters: {FMU parameter: value}, set before
    initialisation. log_variables: FMU variables recorded every sample into the trace, as a plug-in's state.
    call_timeout_s: wall time a sample's FMU calls may take, s (then the run fails, naming the call);
    memory_limit_mb: resident memory of the process that hosts the FMU, MiB (then the run fails); both in
    :data:`LIMITS`. FmuError (a ValueError) naming the file if the FMU cannot run: checked, then started once and ended.
    """
    if fmu is None:
        raise ValueError("no FMU: give controller.options.fmu, the .fmu file (docs/fmi.md)")
    for name, value in (("call_timeout_s", call_timeout_s), ("memory_limit_mb", memory_limit_mb)):
        low, high = LIMITS[name]
        if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
            raise ValueError(f"controller.options.{name}: must be a number in [{low:.10g}, {high:.10g}], got {value!r}")
    checked = read_controller(fmu, variables, parameters, tuple(log_variables))
    limits = (float(call_timeout_s), int(memory_limit_mb * 2**20))
    trial_start(checked, *limits)  # a binary that does not load is bad input too: refused before the run
    if checked.needs_python:
        return PythonFmuController(checked, *limits)
    cls = (
        _with_log_layout(tuple((LOG_PREFIX + v.name, ()) for v in checked.logged)) if checked.logged else FmuController
    )
    return cls(checked, *limits)
