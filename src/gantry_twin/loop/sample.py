"""One sample of the 0.2 ms loop, written once (docs/equations.md, "Sensing and timing"): plant changes, the
encoder, the controller's step, clipping, recording, MuJoCo's ``mj_step``; and the chunk kernel that runs
it for a run of samples with a controller's compiled step (:func:`chunk_kernel`). :mod:`gantry_twin.loop.simulate`
drives it; it names no controller and no contour.
"""

from __future__ import annotations

import glob
import math
import os
import re
from collections.abc import Callable
from typing import NamedTuple

import mujoco
import numpy as np
from numba import types
from numba.core.errors import NumbaError
from numba.core.registry import CPUDispatcher

from gantry_twin.controllers.base import (
    CompiledStep,
)
from gantry_twin.numerics.estimation import clip
from gantry_twin.numerics.jit import kernel, source_digest, specialise
from gantry_twin.plant.effects import amplifier_output, plant_input_v
from gantry_twin.plant.faults import (
    apply_plant_changes,
    cogging_force,
    sensor_glitches,
)
from gantry_twin.plant.sensing import encoder_measure


def load_mj_step() -> types.ExternalFunction | None:
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


mj_step = load_mj_step()


class PlantIO(NamedTuple):
    """What the loop touches in MuJoCo: raw pointers, views into mjData, indices, the DAC limits (2,) V,
    physics steps per sample, the plant's own input offset and force ripple
    (:func:`gantry_twin.plant.effects.input_table`), the amplifier's delay (samples), current-loop gain per
    sample and state (:class:`gantry_twin.plant.effects.Amplifier`).
    """

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
    substeps: int
    input_table: np.ndarray
    delay_samples: int
    current_gain: float
    amplifier_state: np.ndarray


class Recording(NamedTuple):
    """The loop's inputs (sample times, reference rows, disturbance) and the trace arrays it writes.

    Row j holds sample first + j of the run. log: a compiled controller's log
    buffer (:meth:`Trace.allocate_log`; empty for none), log_sizes (keys,)
    the size of each logged value.
    """

    first: int
    t_s: np.ndarray
    rows: np.ndarray
    disturbance_v: np.ndarray
    q_m: np.ndarray
    q_meas_m: np.ndarray
    u_v: np.ndarray
    log: np.ndarray
    log_sizes: np.ndarray


class SampleWork(NamedTuple):
    """One sample: true position m and velocity m/s, measured position m and velocity m/s, command V,
    the controller's log row."""

    q_true: np.ndarray
    dq_true: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    command: np.ndarray
    log_row: np.ndarray


#: Status codes of the chunk function.
STATUS_OK, STATUS_BAD_MEASUREMENT, STATUS_BAD_COMMAND = 0, 1, 2


@kernel(internal=True, nrt=False)
def measure_sample(plant, encoder, sample, changes, k):
    """The encoder's reading of sample k, glitches included; False if not finite."""
    q_true, dq_true = sample.q_true, sample.dq_true
    for i in range(2):
        q_true[i] = plant.qpos[plant.qpos_index[i]]
        dq_true[i] = plant.qvel[plant.dof_index[i]]
    offset, hold, noise = sensor_glitches(changes, k)
    return encoder_measure(encoder, q_true, dq_true, offset, hold, noise, sample.position, sample.velocity)


@kernel(internal=True, nrt=False)
def record_and_step(plant, recording, k, sample, changes):
    """Check the command; record the sample (row k of the recording); hold u (clipped, through the amplifier's
    delay and current loop) and the disturbance (+ cogging, + the plant's own offset and ripple at the true
    position); mj_step ``plant.substeps`` times.

    Returns False if the command is not finite.
    """
    command = sample.command
    for i in range(2):
        if not math.isfinite(command[i]):
            return False
    ctrl, u_max_v, motors, disturbances = plant.ctrl, plant.u_max_v, plant.motor_index, plant.disturbance_index
    q_true, position, disturbance_v = sample.q_true, sample.position, recording.disturbance_v
    for i in range(2):
        u = clip(command[i], -u_max_v[i], u_max_v[i])
        recording.q_m[k, i] = q_true[i]
        recording.q_meas_m[k, i] = position[i]
        recording.u_v[k, i] = u
        ctrl[motors[i]] = amplifier_output(plant.delay_samples, plant.current_gain, plant.amplifier_state, i, u)
        if changes.cogging[i, 0] != 0.0:
            ctrl[disturbances[i]] = disturbance_v[k, i] + cogging_force(changes.cogging, i, q_true[i])
        else:
            ctrl[disturbances[i]] = disturbance_v[k, i]
        ctrl[disturbances[i]] += plant_input_v(plant.input_table, i, q_true[i])
    for _ in range(plant.substeps):
        mj_step(plant.model_address, plant.data_address)
    return True


@kernel(inline=True, internal=True, nrt=False)
def no_log(params, state, out):
    """The log of a controller that logs nothing (inlined: a kernel of its own would be compiled for every
    controller's types, and numba's cache index of it would name them all, the classes of removed plug-ins too)."""


@kernel(internal=True, nrt=False)
def record_log(recording, k, row):
    """Store the log row of the recording's row k into the log buffer (see :meth:`Trace.allocate_log`)."""
    log, sizes = recording.log, recording.log_sizes
    if log.shape[0] == 0:
        return
    n = recording.t_s.shape[0]
    block, at = 0, 0
    for j in range(sizes.shape[0]):
        size = sizes[j]
        for i in range(size):
            log[block + k * size + i] = row[at + i]
        block += n * size
        at += size


@kernel(nrt=False)
def run_chunk(start, stop, plant, encoder, recording, sample, changes, params, state):
    """Samples [start, stop) of the run: changes -> measure -> control -> record -> mj_step; returns (status,
    sample index): (STATUS_OK, stop) or the failed status and the sample it failed at, nothing of it recorded.

    ``controller_step`` and ``controller_log`` are the controller's kernels,
    bound per controller by :func:`chunk_kernel` (compiled) or :func:`_python_chunk`.
    """
    t_s, rows, position, velocity = recording.t_s, recording.rows, sample.position, sample.velocity
    for k in range(start, stop):
        j = k - recording.first
        apply_plant_changes(plant.dof_index, changes, k)
        if not measure_sample(plant, encoder, sample, changes, k):
            return STATUS_BAD_MEASUREMENT, k
        controller_step(params, state, t_s[j], position, velocity, rows[j], sample.command)  # noqa: F821
        if not record_and_step(plant, recording, j, sample, changes):
            return STATUS_BAD_COMMAND, k
        controller_log(params, state, sample.log_row)  # noqa: F821
        record_log(recording, j, sample.log_row)
    return STATUS_OK, stop


@kernel(nrt=False)
def advance_plant(count, plant, encoder, recording, sample, changes):
    """``count`` samples of the plant alone, for a co-simulation step (:mod:`gantry_twin.fmi`): each holds the
    command ``sample.command`` and the disturbance ``recording.disturbance_v[0]`` and steps (:func:`record_and_step`,
    into row 0 of a one-row recording), then the encoder reads the sample after (:func:`measure_sample`): the
    order :func:`run_chunk` runs them in around a controller. Returns (status, samples done)."""
    for k in range(count):
        if not record_and_step(plant, recording, 0, sample, changes):
            return STATUS_BAD_COMMAND, k
        if not measure_sample(plant, encoder, sample, changes, 0):
            return STATUS_BAD_MEASUREMENT, k
    return STATUS_OK, count


_ChunkKey = tuple[Callable[..., object], Callable[..., object] | None, bool]
_chunk_kernels: dict[_ChunkKey, Callable[..., tuple[int, int]]] = {}


def chunk_kernel(compiled: CompiledStep, nrt: bool = False) -> Callable[..., tuple[int, int]]:
    """The compiled chunk function for a controller's compiled step (created once, compiled on first call).

    Its name carries a digest of the step's and log's source files, so an
    edited plug-in compiles anew; numba caches it on disk like every kernel.
    nrt: with numba's reference counting, for a step or log that allocates
    arrays (:func:`needs_reference_counting`); the built-in steps do not.
    """
    key = (compiled.step, compiled.log, nrt)  # the layout is the Python side's (DRC, DARC and DIARC share a kernel)
    found = _chunk_kernels.get(key)
    if found is None:
        log = compiled.log or no_log
        py = getattr(compiled.step, "py_func", compiled.step)
        name = re.sub(r"\W", "_", f"{py.__module__}_{py.__qualname__}_{source_digest(compiled.step, log)}")
        name += "_nrt" if nrt else ""
        # The step's own code is inlined (it is typed once, in here: a separate compile would be finalised twice,
        # and each sample would pass every array of its tuples); what it calls (the law, the least squares, ...) and
        # the log are kernels compiled and cached once, which the chunk links. docs/performance.md, "Compile".
        step = kernel(py, inline=True)
        log = log if isinstance(log, CPUDispatcher) else kernel(log)
        bindings = {"controller_step": step, "controller_log": log}
        # No reference counting in the chunk unless the step needs it: most of the code numba would generate for the
        # chunk, and of its atomic operations per sample, counts the arrays of the nested tuples.
        # Without the interpreter lock while it runs: a live link's server thread serves beside the loop.
        found = specialise(run_chunk, name, bindings, compiled=True, nrt=nrt, nogil=True)
        _chunk_kernels[key] = found
    return found


def needs_reference_counting(error: BaseException) -> bool:
    """True if ``error``, raised by the first call of a chunk kernel without reference counting, is numba's refusal
    to compile it (a step or log that allocates an array says so in several ways): then :func:`chunk_kernel` with
    ``nrt=True`` compiles it, and reports any other compile error as before."""
    return isinstance(error, NumbaError)
