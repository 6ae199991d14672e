"""The 0.2 ms loop: measure -> control -> disturb -> mj_step -> record.

One physics step per controller sample (Ts = the model's timestep, 0.2 ms).
The command is computed from that sample's measurement and held over the
step (zero-order hold, as the DS1103's DAC does). The disturbance actuators
are driven from the scenario's timeline; the controller never sees them.

The loop records into a :class:`Trace` preallocated for the whole run and
hands it to observers (progress bars, live telemetry, pacing) after every
chunk of ``chunk_s`` simulated seconds. Observers only read the trace:
nothing they do changes the simulation.

Two backends run the same equations (docs/performance.md):

* ``reference``: a Python loop that calls ``controller.update()`` every
  sample and ``mujoco.mj_step``; any plug-in controller runs this way, and
  the built-in controllers then run their kernels uncompiled.
* ``compiled``: for the built-in controllers (drc, darc, diarc, pd), each
  chunk is one numba kernel that measures, runs the controller's compiled
  step, records and calls MuJoCo's C ``mj_step`` directly (through the
  shared library the mujoco wheel ships), with no Python in the 0.2 ms loop.
  It leaves the controller object in the state the reference run leaves.
"""

from __future__ import annotations

import glob
import math
import os
from collections.abc import Callable, Sequence
from typing import Literal, NamedTuple

import mujoco
import numpy as np
from numba import types

from gantry_twin._jit import is_cached, kernel
from gantry_twin._jit import reference as uncompiled
from gantry_twin.changes import PlantChanges
from gantry_twin.controllers.arc import CLOCK_LAMBDA_MAX, DARC, DIARC, DRC, arc_step
from gantry_twin.controllers.base import Controller, Measurement, ReferenceSample, RunContext
from gantry_twin.controllers.pd import PD, pd_step
from gantry_twin.paths import Path, Reference, TimingLaw, contour_error, reference
from gantry_twin.plant import Plant
from gantry_twin.sensing import Encoder, SensingConfig
from gantry_twin.taskframe import task_errors
from gantry_twin.trace import Observer, RunInfo, SimulationError, Trace

#: A disturbance timeline: times (N,) s -> input disturbance (N, 2) volts.
Disturbance = Callable[[np.ndarray], np.ndarray]


def _finish_chunk(trace: Trace, ref: Reference, path: Path, start: int, stop: int) -> None:
    """Derived errors for samples [start, stop): e, eps_n and the true eps_c."""
    e = trace.q_m[start:stop] - ref.q_d[start:stop]
    trace.e_m[start:stop] = e
    trace.eps_n_m[start:stop] = task_errors(ref.alpha[start:stop], e)[:, 0]
    trace.eps_c_m[start:stop], _ = contour_error(path, trace.q_m[start:stop], ref.phi[start:stop])
    trace.filled = stop


Backend = Literal["auto", "compiled", "reference"]


def _load_mj_step() -> types.ExternalFunction | None:
    """MuJoCo's C ``mj_step(const mjModel*, mjData*)`` for numba, or None if the library is not found.

    The mujoco wheel ships ``libmujoco.so.*`` (``libmujoco*.dylib`` on macOS)
    next to its Python module, which has already loaded it; making its
    symbols visible to LLVM lets compiled code call ``mj_step`` by name.
    The pointers are passed as integers (MjModel._address, MjData._address).
    """
    import llvmlite.binding as llvm

    here = os.path.dirname(mujoco.__file__)
    for pattern in ("libmujoco.so*", "libmujoco*.dylib"):
        for path in sorted(glob.glob(os.path.join(here, pattern))):
            try:
                llvm.load_library_permanently(path)
            except RuntimeError:
                continue
            return types.ExternalFunction("mj_step", types.void(types.intp, types.intp))
    return None


mj_step = _load_mj_step()


class PlantIO(NamedTuple):
    """What the compiled loop touches in MuJoCo: raw pointers, views into mjData, indices."""

    model_address: int
    data_address: int
    qpos: np.ndarray
    qvel: np.ndarray
    ctrl: np.ndarray
    qpos_index: np.ndarray
    dof_index: np.ndarray
    motor_index: np.ndarray
    disturbance_index: np.ndarray
    u_max_v: np.ndarray


class SensorState(NamedTuple):
    """The encoder of :mod:`gantry_twin.sensing` for the compiled loop; previous_m (2,) is its memory."""

    quantize: bool
    resolution_m: float
    velocity_by_difference: bool
    sample_period_s: float
    previous_m: np.ndarray


class ChangeSchedule(NamedTuple):
    """Per-sample plant and sensor changes (gantry_twin.changes) for both loops.

    The first three are views of mjModel memory the loop writes into. Each
    schedule is (N, ...) when the run has that kind of change, else empty
    (0, ...), which the loop reads as "unchanged". cogging (2, 3): amplitude V,
    pitch m, phase rad per axis (amplitude 0: no ripple).
    """

    dof_damping: np.ndarray
    dof_frictionloss: np.ndarray
    body_mass: np.ndarray
    payload_body: int
    damping_n_s_m: np.ndarray
    frictionloss_n: np.ndarray
    payload_kg: np.ndarray
    cogging: np.ndarray
    offset_m: np.ndarray
    hold: np.ndarray
    velocity_noise_m_s: np.ndarray


def change_schedule(plant: Plant, changes: PlantChanges | None, t: np.ndarray) -> ChangeSchedule:
    """The loop's per-sample arrays for ``changes`` over the sample times t (N,) s."""
    model = plant.model
    none2, none1 = np.empty((0, 2)), np.empty(0)
    changes = changes or PlantChanges()
    cogging = np.zeros((2, 3))
    cogging[:, 1] = 1.0
    for ripple in changes.cogging:
        cogging[ripple.axis_index] = (ripple.amplitude_v, ripple.pitch_m, ripple.phase_rad)
    body = -1
    if changes.payload_change:
        if plant.payload_body_id is None:
            raise ValueError("changes.payload_change: the plant has no payload body to change; build it with "
                             "Plant(payload, payload_body=True)")
        body = plant.payload_body_id
    glitches = changes.encoder_glitch
    return ChangeSchedule(
        model.dof_damping, model.dof_frictionloss, model.body_mass, body,
        np.ascontiguousarray(changes.damping_n_s_m(plant, t)) if changes.friction_drift else none2,
        np.ascontiguousarray(changes.frictionloss_n(plant, t)) if changes.friction_drift else none2,
        np.ascontiguousarray(changes.payload_mass_kg(plant, t)) if changes.payload_change else none1,
        cogging,
        np.ascontiguousarray(changes.position_offset_m(t)) if any(g.kind == "spike" for g in glitches) else none2,
        np.ascontiguousarray(changes.hold_mask(t)) if any(g.kind == "hold" for g in glitches) else
        np.empty(0, dtype=np.bool_),
        np.ascontiguousarray(changes.velocity_noise_m_s(t)) if changes.velocity_noise is not None else none2,
    )  # fmt: skip


@kernel
def _change_plant(dof_index, changes, k):
    """Write sample k's scheduled joint damping, Coulomb level and payload mass into the model.

    Only body_mass changes; MuJoCo derives the mass matrix from it at every
    step. dof_invweight0 (set at compile time, used to scale constraint
    regularisation) keeps its unloaded value: with this model's stiff friction
    that changes nothing measurable (tests/test_changes_loop.py compares with a
    plant compiled with the payload).
    """
    if changes.damping_n_s_m.shape[0] > 0:
        for i in range(2):
            changes.dof_damping[dof_index[i]] = changes.damping_n_s_m[k, i]
            changes.dof_frictionloss[dof_index[i]] = changes.frictionloss_n[k, i]
    if changes.payload_kg.shape[0] > 0:
        changes.body_mass[changes.payload_body] = changes.payload_kg[k]


@kernel
def _cogging_v(changes, axis, q_m):
    """Cogging force of one axis at the true position q_m, volts (as PlantChanges.cogging_force_v)."""
    c = changes.cogging
    if c[axis, 0] == 0.0:
        return 0.0
    return c[axis, 0] * math.sin(2.0 * math.pi * q_m / c[axis, 1] + c[axis, 2])


class Recording(NamedTuple):
    """Inputs (reference rows, disturbance) and the trace arrays the compiled loop writes."""

    rows: np.ndarray
    disturbance_v: np.ndarray
    q_m: np.ndarray
    q_meas_m: np.ndarray
    u_v: np.ndarray


class SampleWork(NamedTuple):
    """One sample: true position m, measured position m and velocity m/s, command volts (2,) each."""

    q_true: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    command: np.ndarray


#: Status codes of the compiled chunk kernels.
STATUS_OK, STATUS_BAD_MEASUREMENT, STATUS_BAD_COMMAND = 0, 1, 2


@kernel
def _measure(plant, sensor, sample, changes, k):
    """Encoder reading of sample k, glitches included (same arithmetic as sensing.Encoder); False if not finite."""
    qpos, qvel, qpos_index, dof_index = plant.qpos, plant.qvel, plant.qpos_index, plant.dof_index
    previous_m, resolution_m = sensor.previous_m, sensor.resolution_m
    q_true, position, velocity = sample.q_true, sample.position, sample.velocity
    spikes, noise = changes.offset_m.shape[0] > 0, changes.velocity_noise_m_s.shape[0] > 0
    held = changes.hold.shape[0] > 0 and changes.hold[k]
    finite = True
    for i in range(2):
        q = qpos[qpos_index[i]]
        q_true[i] = q
        position[i] = np.rint(q / resolution_m) * resolution_m if sensor.quantize else q
        if spikes:
            position[i] = position[i] + changes.offset_m[k, i]
        if held:
            position[i] = previous_m[i]
        if sensor.velocity_by_difference:
            velocity[i] = (position[i] - previous_m[i]) / sensor.sample_period_s
        else:
            velocity[i] = qvel[dof_index[i]]
        if noise:
            velocity[i] = velocity[i] + changes.velocity_noise_m_s[k, i]
        previous_m[i] = position[i]
        finite = finite and np.isfinite(position[i]) and np.isfinite(velocity[i])
    return finite


@kernel
def _record_and_step(plant, recording, k, sample, command, changes):
    """Check the command; record the sample; hold u and the disturbance (+ cogging); mj_step. False if u not finite."""
    kept = sample.command
    for i in range(2):
        kept[i] = command[i]
        if not np.isfinite(command[i]):
            return False
    ctrl, u_max_v, motors, disturbances = plant.ctrl, plant.u_max_v, plant.motor_index, plant.disturbance_index
    q_true, position = sample.q_true, sample.position
    _, disturbance_v, q_m, q_meas_m, u_v = recording
    for i in range(2):
        u = min(max(command[i], -u_max_v[i]), u_max_v[i])
        q_m[k, i] = q_true[i]
        q_meas_m[k, i] = position[i]
        u_v[k, i] = u
        ctrl[motors[i]] = u
        if changes.cogging[i, 0] != 0.0:
            ctrl[disturbances[i]] = disturbance_v[k, i] + _cogging_v(changes, i, q_true[i])
        else:
            ctrl[disturbances[i]] = disturbance_v[k, i]
    mj_step(plant.model_address, plant.data_address)
    return True


@kernel
def _run_arc_chunk(start, stop, plant, sensor, recording, sample, changes, params, state, theta_log, dc_log,
                   gamma_log, lambda_log):  # fmt: skip
    """Samples [start, stop) with DRC/DARC/DIARC; returns (status, sample index)."""
    rows, position, velocity = recording.rows, sample.position, sample.velocity
    theta, dc, u_v = state.theta, state.dc, state.law.u_v
    gamma, clock = state.estimator.gamma, state.estimator.clock
    for k in range(start, stop):
        _change_plant(plant.dof_index, changes, k)
        if not _measure(plant, sensor, sample, changes, k):
            return STATUS_BAD_MEASUREMENT, k
        arc_step(params, state, position, velocity, rows[k])
        if not _record_and_step(plant, recording, k, sample, u_v, changes):
            return STATUS_BAD_COMMAND, k
        if theta_log.shape[0] > 0:
            theta_log[k, :] = theta
        if dc_log.shape[0] > 0:
            dc_log[k, :] = dc
        if gamma_log.shape[0] > 0:
            for j in range(gamma_log.shape[1]):
                gamma_log[k, j] = gamma[j, j]
        if lambda_log.shape[0] > 0:
            lambda_log[k] = clock[CLOCK_LAMBDA_MAX]
    return STATUS_OK, stop


@kernel
def _run_pd_chunk(start, stop, plant, sensor, recording, sample, changes, params, u_v):
    """Samples [start, stop) with the PD baseline; returns (status, sample index)."""
    rows, position, velocity = recording.rows, sample.position, sample.velocity
    for k in range(start, stop):
        _change_plant(plant.dof_index, changes, k)
        if not _measure(plant, sensor, sample, changes, k):
            return STATUS_BAD_MEASUREMENT, k
        pd_step(params, position, velocity, rows[k], u_v)
        if not _record_and_step(plant, recording, k, sample, u_v, changes):
            return STATUS_BAD_COMMAND, k
    return STATUS_OK, stop


#: The controllers the compiled backend runs (exact types: a subclass may override update()).
COMPILED_CONTROLLERS = (DRC, DARC, DIARC, PD)


def loop_needs_compiling(controller: Controller) -> bool:
    """True if simulate() with this controller will first compile the loop (about 25 s, once per machine)."""
    if type(controller) not in COMPILED_CONTROLLERS or not compiled_available():
        return False
    return not is_cached(_run_pd_chunk if isinstance(controller, PD) else _run_arc_chunk)


def compiled_available() -> bool:
    """True if MuJoCo's mj_step could be made callable from compiled code."""
    return mj_step is not None


def simulate(
    plant: Plant,
    path: Path,
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
) -> Trace:
    """Run the closed loop for ``duration_s`` seconds and return the trace.

    The plant starts at q_d(0) moving at q_d'(0): for an ``on_path`` timing
    law that is the paper's "already running" start; for ``rest``, standstill.
    backend: ``auto`` (compiled for the built-in controllers drc, darc, diarc,
    pd when MuJoCo's library is found, else reference), ``compiled`` or
    ``reference``; both give the same trace (tests/test_backends.py).
    changes: faults applied to the plant and the sensor during the run
    (:mod:`gantry_twin.changes`), never shown to the controller; the trace
    then records the true theta over time (``true_theta_t``). A payload
    change needs a plant built with ``payload_body=True``. The model's
    damping, friction and masses are restored after the run.
    """
    if backend not in ("auto", "compiled", "reference"):
        raise ValueError(f"backend must be 'auto', 'compiled' or 'reference', got {backend!r}")
    builtin = type(controller) in COMPILED_CONTROLLERS
    if backend == "compiled" and not builtin:
        raise ValueError(f"backend 'compiled' runs only {', '.join(c.__name__ for c in COMPILED_CONTROLLERS)}; "
                         f"got {type(controller).__name__}")  # fmt: skip
    if backend == "compiled" and not compiled_available():
        raise RuntimeError("backend 'compiled': MuJoCo's shared library was not found next to the mujoco module")
    compiled = backend == "compiled" or (backend == "auto" and builtin and compiled_available())

    sensing = sensing or SensingConfig()
    ts = plant.timestep_s
    n = int(round(duration_s / ts))
    if n < 2:
        raise ValueError(f"duration_s must hold at least two samples of {ts} s, got {duration_s}")
    t = np.arange(n) * ts
    ref = reference(path, timing, t)
    rows = np.ascontiguousarray(ref.packed())
    dist = np.zeros((n, 2)) if disturbance is None else np.asarray(disturbance(t), dtype=float)
    if dist.shape != (n, 2):
        raise ValueError(f"disturbance must give shape ({n}, 2) volts, got {dist.shape}")
    dist = np.ascontiguousarray(dist)

    schedule = change_schedule(plant, changes, t)
    model = plant.model
    saved = (model.dof_damping.copy(), model.dof_frictionloss.copy(), model.body_mass.copy())
    try:
        plant.reset(ref.q_d[0], ref.dq_d[0])
        encoder = Encoder(sensing, ts)
        encoder.reset(plant.q_m, plant.dq_m_s)
        trace = Trace.allocate(ref, dist, plant.true_parameters())
        if changes is not None and not changes.empty:
            trace.true_theta_t = changes.true_parameters_over_time(plant, t)
            trace.true_theta = trace.true_theta_t[0].copy()
        info = RunInfo(plant, path, timing, ref, duration_s, controller_name or type(controller).__name__)
        for observer in observers:
            observer.on_start(info, trace)
        chunk = max(1, int(round(chunk_s / ts)))
        run = _run_compiled if compiled else _run_reference
        for start, stop in run(plant, encoder, controller, trace, rows, chunk, schedule):
            _finish_chunk(trace, ref, path, start, stop)
            for observer in observers:
                observer.on_chunk(trace, start, stop)
        for observer in observers:
            observer.on_end(trace)
    finally:
        model.dof_damping[:], model.dof_frictionloss[:], model.body_mass[:] = saved
    return trace


def _bad_measurement(t_s: float, position: np.ndarray, velocity: np.ndarray) -> SimulationError:
    return SimulationError(f"non-finite measurement at t = {t_s:.4f} s: q = {position}, q' = {velocity}")


def _bad_command(t_s: float, command: np.ndarray) -> SimulationError:
    return SimulationError(f"controller returned {command!r} at t = {t_s:.4f} s; expected 2 finite volts")


def _run_reference(plant: Plant, encoder: Encoder, controller: Controller, trace: Trace, rows: np.ndarray, chunk: int,
                   changes: ChangeSchedule):  # fmt: skip
    """The Python loop, chunk by chunk: yields (start, stop) after filling samples [start, stop)."""
    model, data = plant.model, plant.data
    u_max = plant.ctrl_range_v[:, 1]
    motors, dist_act = plant.motor_index, plant.disturbance_index
    t, dist, n = trace.t_s, trace.disturbance_v, trace.t_s.size
    change_plant, cogging_v = uncompiled(_change_plant), uncompiled(_cogging_v)
    dof_index = np.ascontiguousarray(plant.dof_index, dtype=np.int64)
    spikes, holds, noise = changes.offset_m, changes.hold, changes.velocity_noise_m_s
    cogging = changes.cogging[:, 0] != 0.0
    for start in range(0, n, chunk):
        stop = min(n, start + chunk)
        for k in range(start, stop):
            change_plant(dof_index, changes, k)
            q_true = plant.q_m.copy()
            position, velocity = encoder.measure(q_true, plant.dq_m_s, spikes[k] if spikes.shape[0] else None,
                                                 bool(holds[k]) if holds.shape[0] else False,
                                                 noise[k] if noise.shape[0] else None)  # fmt: skip
            if not (np.isfinite(position).all() and np.isfinite(velocity).all()):
                raise _bad_measurement(t[k], position, velocity)
            measurement = Measurement(float(t[k]), position, velocity)
            if k == 0:
                controller.reset(RunContext(plant.timestep_s, u_max.copy(), measurement))
            command = np.asarray(controller.update(measurement, ReferenceSample.from_row(rows[k])), dtype=float)
            if command.shape != (2,) or not np.isfinite(command).all():
                raise _bad_command(t[k], command)
            u = np.clip(command, -u_max, u_max)
            trace.q_m[k] = q_true
            trace.q_meas_m[k] = position
            trace.u_v[k] = u
            trace.record_state(k, controller.state_for_logging())
            data.ctrl[motors] = u
            data.ctrl[dist_act] = dist[k]
            for i in np.flatnonzero(cogging):
                data.ctrl[dist_act[i]] = dist[k, i] + cogging_v(changes, int(i), float(q_true[i]))
            mujoco.mj_step(model, data)
        yield start, stop


def _run_compiled(plant: Plant, encoder: Encoder, controller: Controller, trace: Trace, rows: np.ndarray, chunk: int,
                  changes: ChangeSchedule):  # fmt: skip
    """The compiled loop: one kernel call per chunk; yields (start, stop) like :func:`_run_reference`."""
    t, n = trace.t_s, trace.t_s.size
    u_max = np.ascontiguousarray(plant.ctrl_range_v[:, 1])
    config = encoder.config
    sensor = SensorState(bool(config.quantize), float(config.resolution_m), bool(config.velocity_by_difference),
                         float(plant.timestep_s), encoder._previous_m.copy())  # fmt: skip
    # The first measurement, for the controller's RunContext (the kernel measures it again).
    spikes, holds, noise = changes.offset_m, changes.hold, changes.velocity_noise_m_s
    position, velocity = encoder.measure(plant.q_m.copy(), plant.dq_m_s, spikes[0] if spikes.shape[0] else None,
                                         bool(holds[0]) if holds.shape[0] else False,
                                         noise[0] if noise.shape[0] else None)  # fmt: skip
    if not (np.isfinite(position).all() and np.isfinite(velocity).all()):
        raise _bad_measurement(t[0], position, velocity)
    controller.reset(RunContext(plant.timestep_s, u_max.copy(), Measurement(float(t[0]), position, velocity)))
    trace.allocate_state(controller.state_for_logging())

    data = plant.data
    io = PlantIO(plant.model._address, data._address, data.qpos, data.qvel, data.ctrl,
                 *(np.ascontiguousarray(i, dtype=np.int64) for i in (plant.qpos_index, plant.dof_index,
                                                                     plant.motor_index, plant.disturbance_index)),
                 u_max)  # fmt: skip
    recording = Recording(rows, trace.disturbance_v, trace.q_m, trace.q_meas_m, trace.u_v)
    sample = SampleWork(np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2))
    if isinstance(controller, PD):
        params, u_v = controller.kernel_arguments(), np.zeros(2)

        def run_chunk(start: int, stop: int) -> tuple[int, int]:
            return _run_pd_chunk(start, stop, io, sensor, recording, sample, changes, params, u_v)
    else:
        arc_params, state = controller.kernel_arguments()
        logs = trace.controller_state
        theta_log = logs.get("theta_hat", np.empty((0, 8)))
        dc_log = logs.get("dc_hat", np.empty((0, 2)))
        gamma_log = logs.get("gamma_diag", np.empty((0, 8)))
        lambda_log = logs.get("gamma_lambda_max", np.empty(0))

        def run_chunk(start: int, stop: int) -> tuple[int, int]:
            return _run_arc_chunk(start, stop, io, sensor, recording, sample, changes, arc_params, state, theta_log,
                                  dc_log, gamma_log, lambda_log)  # fmt: skip

    for start in range(0, n, chunk):
        stop = min(n, start + chunk)
        status, k = run_chunk(start, stop)
        if status == STATUS_BAD_MEASUREMENT:
            raise _bad_measurement(t[k], sample.position.copy(), sample.velocity.copy())
        if status == STATUS_BAD_COMMAND:
            raise _bad_command(t[k], sample.command.copy())
        yield start, stop
