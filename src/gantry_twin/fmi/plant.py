"""The twin's plant stepped by a co-simulation master (docs/fmi.md, "The plant as an FMU").

:class:`CoSimPlant` is the plant half of the 0.2 ms loop with the controller taken out: a master sets the motor
commands and the input disturbances (volts), asks for a step of whole samples, and reads the encoder (quantised,
velocity by backward difference) and the true joint state. Each sample is the loop's own
(:func:`gantry_twin.loop.sample.advance_plant`: :func:`~gantry_twin.loop.sample.record_and_step` then
:func:`~gantry_twin.loop.sample.measure_sample`), compiled when MuJoCo's library is found, else on the reference
backend. The FMI plumbing (pythonfmu) is :mod:`gantry_twin.fmi.plant_slave`; building the FMU
:mod:`gantry_twin.fmi.plant_export`.

Parameters (FMI ``parameter`` variables, named as the scenario's fields are): ``payload.mass_kg``; the start
state ``start.x_m``, ``start.y_m``, ``start.dx_m_s``, ``start.dy_m_s``; per axis the friction: ``friction.<axis>.fc_n``
(Coulomb level, N) and ``friction.<axis>.sigma2_ns_m`` (viscous, N s/m) on both machines, and on a LuGre plant
(the rig) also ``fs_n``, ``vs_m_s``, ``sigma0_n_m``, ``sigma1_ns_m`` (:class:`gantry_twin.plant.friction.LuGreAxis`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from gantry_twin.loop.sample import STATUS_OK, Recording, SampleWork, advance_plant
from gantry_twin.loop.simulate import compiled_available, plant_io, reference_record_and_step
from gantry_twin.numerics.jit import reference, specialise
from gantry_twin.plant.faults import change_schedule
from gantry_twin.plant.friction import Friction, LuGreAxis
from gantry_twin.plant.model import AXES, Payload, Plant
from gantry_twin.plant.sensing import Encoder, SensingConfig, encoder_measure

#: The FMU's inputs (volts): the motor commands and the input disturbances, held over a step.
INPUTS = ("u_x_v", "u_y_v", "d_x_v", "d_y_v")
#: The FMU's outputs: the encoder (m, m/s) and the true joint state (m, m/s), the controller convention's names.
MEASURED = ("x_m", "y_m", "dx_m_s", "dy_m_s")
TRUE = ("x_true_m", "y_true_m", "dx_true_m_s", "dy_true_m_s")
OUTPUTS = MEASURED + TRUE
#: The start state's parameters: position m and velocity m/s (X, Y).
START = ("start.x_m", "start.y_m", "start.dx_m_s", "start.dy_m_s")
#: Friction parameters per axis: both machines' (Coulomb level, viscous), then LuGre's other four.
FRICTION_COMMON = ("fc_n", "sigma2_ns_m")
FRICTION_LUGRE = ("fs_n", "vs_m_s", "sigma0_n_m", "sigma1_ns_m")
PAYLOAD = "payload.mass_kg"


#: The friction parameters in words, with their units.
FRICTION_WORDS = {
    "fc_n": "Coulomb level, N",
    "sigma2_ns_m": "viscous coefficient, N s/m",
    "fs_n": "LuGre static (break-away) level, N",
    "vs_m_s": "LuGre Stribeck velocity, m/s",
    "sigma0_n_m": "LuGre bristle stiffness, N/m",
    "sigma1_ns_m": "LuGre bristle damping, N s/m",
}


def descriptions(parameters: Mapping[str, float]) -> dict[str, dict[str, str]]:
    """Every variable's description, by kind, in the FMU's order (parameters, inputs, outputs)."""
    params = {PAYLOAD: "payload on the X carriage, kg (0 to 20)"}
    params.update(zip(START, ("start position X, m", "start position Y, m", "start velocity X, m/s",
                              "start velocity Y, m/s"), strict=True))  # fmt: skip
    for name in parameters:
        if name.startswith("friction."):
            _, axis, field = name.split(".")
            what, unit = FRICTION_WORDS[field].split(", ")
            params[name] = f"{what} of axis {axis.upper()}, {unit}"
    inputs = {
        "u_x_v": "motor command X, V (clipped to the DAC's +-10 V, held over the step)",
        "u_y_v": "motor command Y, V (clipped to the DAC's +-10 V, held over the step)",
        "d_x_v": "input disturbance X, V (added at the motor, held over the step)",
        "d_y_v": "input disturbance Y, V (added at the motor, held over the step)",
    }
    outputs = dict(
        zip(
            (*MEASURED, *TRUE),
            (
                "encoder position X, m (0.5 um counts)",
                "encoder position Y, m (0.5 um counts)",
                "velocity X by backward difference of the encoder, m/s",
                "velocity Y by backward difference of the encoder, m/s",
                "true position X, m",
                "true position Y, m",
                "true velocity X, m/s",
                "true velocity Y, m/s",
            ),
            strict=True,
        )
    )
    return {"parameter_descriptions": params, "input_descriptions": inputs, "output_descriptions": outputs}


def parameter_names(lugre: bool) -> tuple[str, ...]:
    """The FMU's parameters, in order, for a LuGre plant (the rig) or a Coulomb one (the paper's)."""
    return (PAYLOAD, *START, *(f"friction.{axis}.{field}" for axis in AXES for field in parameter_fields(lugre)))


def parameter_fields(lugre: bool) -> tuple[str, ...]:
    """The friction parameters of one axis (``friction.<axis>.<field>``)."""
    return FRICTION_COMMON + (FRICTION_LUGRE if lugre else ())


def default_parameters(plant: Plant) -> dict[str, float]:
    """The parameters of ``plant`` as built (its payload, at rest at the origin, its model file's friction)."""
    values = {PAYLOAD: float(plant.payload.mass_kg), **dict.fromkeys(START, 0.0)}
    lugre = plant.lugre_parameters()
    for i, axis in enumerate(AXES):
        p, dof = lugre[i], int(plant.dof_index[i])
        if p is None:
            found = {"fc_n": plant.model.dof_frictionloss[dof], "sigma2_ns_m": plant.model.dof_damping[dof]}
        else:
            found = p._asdict()
        for field in parameter_fields(p is not None):
            values[f"friction.{axis}.{field}"] = float(found[field])
    return values


def build_plant(model_file: Path, lugre: bool, parameters: dict[str, float]) -> Plant:
    """The plant of ``model_file`` with the parameters' payload and friction (ValueError naming the parameter
    when one is out of its range)."""
    payload = Payload(mass_kg=parameters[PAYLOAD])
    if not lugre:
        plant = Plant(payload, model_file)
        for i, axis in enumerate(AXES):
            for field, target in (("fc_n", plant.model.dof_frictionloss), ("sigma2_ns_m", plant.model.dof_damping)):
                value = parameters[f"friction.{axis}.{field}"]
                if not (math.isfinite(value) and value >= 0.0):
                    raise ValueError(f"friction.{axis}.{field}: must be a finite number >= 0, got {value!r}")
                target[int(plant.dof_index[i])] = value
        return plant
    axes = {}
    for axis in AXES:
        given = {field: parameters[f"friction.{axis}.{field}"] for field in parameter_fields(True)}
        try:
            axes[axis] = LuGreAxis(**given)
        except ValueError as exc:
            raise ValueError(f"friction.{axis}.{str(exc).removeprefix('lugre.')}") from None
    return Plant(payload, model_file, friction=Friction(model="lugre", **axes))


def whole_samples(step_size_s: float, sample_period_s: float) -> int | None:
    """The communication step as a count of samples, or None unless it is a whole multiple (>= 1) of the sample
    period (to a relative 1e-9 of a sample: 0.001 / 0.0002 is 5.000000000000001 in binary)."""
    if not math.isfinite(step_size_s) or step_size_s <= 0.0:
        return None
    count = round(step_size_s / sample_period_s)
    return count if count >= 1 and abs(step_size_s / sample_period_s - count) <= 1e-9 * count else None


class CoSimPlant:
    """The plant, its encoder and the loop's sample kernels, stepped a whole number of samples at a time."""

    def __init__(self, plant: Plant, start_m: np.ndarray, start_m_s: np.ndarray, compiled: bool | None = None) -> None:
        """Put the plant at ``start_m`` moving at ``start_m_s`` (X, Y) and read the encoder: the outputs at t = 0.

        compiled: the compiled sample (the default when MuJoCo's library is found) or the reference one.
        """
        self.plant = plant
        self.sample_period_s = plant.timestep_s
        plant.reset(np.asarray(start_m, dtype=float), np.asarray(start_m_s, dtype=float))
        encoder = Encoder(SensingConfig(), plant.timestep_s)
        encoder.reset(plant.q_m, plant.dq_m_s)
        self.encoder = encoder.state
        self.io = plant_io(plant)
        self.changes = change_schedule(plant, None, np.zeros(0))
        # One row: the held disturbance and scratch for what record_and_step records; no controller log.
        rows = (np.zeros((1, 2)) for _ in range(4))
        self.recording = Recording(0, np.zeros(1), np.zeros((1, 9)), *rows, np.zeros(0), np.zeros(0, dtype=np.int64))
        self.sample = SampleWork(*(np.zeros(2) for _ in range(5)), np.zeros(0))
        compiled = compiled_available() if compiled is None else compiled
        if compiled:
            self._advance = advance_plant
        else:
            self._advance = specialise(
                advance_plant, "python", {"record_and_step": reference_record_and_step(plant)}, compiled=False
            )
        glitch = self.changes.none
        reference(encoder_measure)(
            self.encoder, plant.q_m.copy(), plant.dq_m_s.copy(), glitch, False, glitch, *self.sample[2:4]
        )
        self._true()
        self.time_s = 0.0

    def _true(self) -> None:
        """The sample's true joint state from MuJoCo (the encoder's kernel reads it the same way)."""
        self.sample.q_true[:] = self.plant.q_m
        self.sample.dq_true[:] = self.plant.dq_m_s

    def advance(self, samples: int, u_v: np.ndarray, d_v: np.ndarray) -> str | None:
        """``samples`` samples with the commands ``u_v`` and disturbances ``d_v`` (X, Y) V held (clipped to the
        DAC's range as the loop's are); None, or what went wrong (a non-finite input, command or measurement)."""
        self.sample.command[:] = u_v
        self.recording.disturbance_v[0] = d_v
        if not np.all(np.isfinite(self.recording.disturbance_v)):
            x, y = (float(v) for v in self.recording.disturbance_v[0])
            return f"disturbance ({x!r}, {y!r}) V is not finite"
        status, done = self._advance(samples, self.io, self.encoder, self.recording, self.sample, self.changes)
        self.time_s += done * self.sample_period_s
        self._true()
        if status != STATUS_OK:
            what = "command" if not np.all(np.isfinite(self.sample.command)) else "measurement"
            return f"non-finite {what} after {done} samples of the step"
        return None

    def outputs(self) -> dict[str, float]:
        """The encoder's reading and the true state of the last sample, by output name."""
        s = self.sample
        values = (*s.position, *s.velocity, *s.q_true, *s.dq_true)
        return {name: float(v) for name, v in zip(OUTPUTS, values, strict=True)}
