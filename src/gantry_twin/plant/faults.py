"""Plant changes during a run: what a fault scenario does to the machine.

A :class:`PlantChanges` is a declarative, validated description (:class:`FrictionDrift`,
:class:`PayloadChange`, :class:`CoggingRipple`, :class:`EncoderGlitch`, :class:`VelocityNoise`). Each change
acts on the MuJoCo model or on the sensor, never on the controller. This module only turns the description
into per-sample schedules over the run's sample times (:func:`change_schedule`); the loop applies them.
:meth:`PlantChanges.true_parameters_over_time` is the true theta the estimates are judged against.
Validation errors are one line naming the field and its allowed range.

(docs/health.md, "Plant changes")
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import numpy as np

from gantry_twin.numerics.jit import kernel, reference
from gantry_twin.plant.friction import identified_af_b, lugre_parameters
from gantry_twin.plant.model import AXES, Axis, PayloadMass, Plant, moving_masses_kg
from gantry_twin.settings import Count, Range, Vector, fmt, rule, validated

#: Latest time a change may name, s.
TIME_MAX_S = 1.0e6
#: The allowed values of the change parameters, in the units their names carry.
TimeS = Range(0.0, TIME_MAX_S, "s")
Viscous = Range(0.0, 10.0, "V/(m/s)")
Coulomb = Range(0.0, 5.0, "V")
CoggingAmplitude = Range(0.0, 2.0, "V")
#: Shorter pitches alias: at 0.4 m/s the carriage moves 80 um per 0.2 ms sample.
CoggingPitch = Range(1.0e-3, 1.0, "m")
Phase = Range(-2.0 * math.pi, 2.0 * math.pi, "rad")
SPIKE_OFFSET_MAX_M = 1.0e-3
SpikeOffset = Range(-SPIKE_OFFSET_MAX_M, SPIKE_OFFSET_MAX_M, "m")
HoldSamples = Count(1, 10000)
VelocityNoiseStd = Vector(Range(0.0, 1.0, "m/s"), AXES)
Seed = Count(0, 2**63 - 1)


def _ramp(t: np.ndarray, start_s: float, end_s: float, v0: float, v1: float) -> np.ndarray:
    """v0 before start_s, v1 after end_s, linear in between."""
    return v0 + (v1 - v0) * np.clip((t - start_s) / (end_s - start_s), 0.0, 1.0)


def _sample_at(t: np.ndarray, time_s: float) -> int | None:
    """Index of the sample nearest to time_s, or None if time_s is outside the run."""
    if t.size == 0:
        return None
    half = 0.5 * (t[1] - t[0]) if t.size > 1 else 0.0
    if time_s < t[0] - half or time_s > t[-1] + half:
        return None
    return int(np.argmin(np.abs(t - time_s)))


def _after(start_s: float, end_s: float) -> None:
    if not end_s > start_s:
        raise rule("end_s", f"must be after start_s = {fmt(start_s)} s, got {fmt(end_s)}")


@validated("friction_drift")
class FrictionDrift:
    """Friction of one axis drifting linearly from ``start_s`` to ``end_s``.

    viscous_to_v_s_m: B at ``end_s``, V/(m/s) (None: B does not drift).
    viscous_from_v_s_m: B up to ``start_s`` (None: the plant's own B).
    coulomb_to_v / coulomb_from_v: the same for Af, volts.
    In SI the model gets B * gear (N s/m) and Af * gear (N). On a LuGre axis
    these are sigma2 / gear and Fc / gear (Fs keeps its ratio to Fc); the
    true theta is then the paper's identification of the drifted friction.
    """

    axis: Axis
    start_s: TimeS
    end_s: TimeS
    viscous_to_v_s_m: Viscous | None = None
    viscous_from_v_s_m: Viscous | None = None
    coulomb_to_v: Coulomb | None = None
    coulomb_from_v: Coulomb | None = None

    def __post_init__(self) -> None:
        _after(self.start_s, self.end_s)
        if self.viscous_to_v_s_m is None and self.coulomb_to_v is None:
            raise rule("viscous_to_v_s_m", "give it or coulomb_to_v (a drift must move B or Af)")
        if self.viscous_from_v_s_m is not None and self.viscous_to_v_s_m is None:
            raise rule("viscous_to_v_s_m", "required when viscous_from_v_s_m is given")
        if self.coulomb_from_v is not None and self.coulomb_to_v is None:
            raise rule("coulomb_to_v", "required when coulomb_from_v is given")

    @property
    def axis_index(self) -> int:
        return AXES.index(self.axis)


@validated("payload_change")
class PayloadChange:
    """From ``time_s`` on, the payload on the X carriage weighs ``mass_kg`` (0: dropped)."""

    time_s: TimeS
    mass_kg: PayloadMass


@validated("cogging")
class CoggingRipple:
    """Position-periodic force on one axis: amplitude_v sin(2 pi q / pitch_m + phase_rad), volts."""

    axis: Axis
    amplitude_v: CoggingAmplitude
    pitch_m: CoggingPitch
    phase_rad: Phase = 0.0

    @property
    def axis_index(self) -> int:
        return AXES.index(self.axis)


@validated("encoder_glitch")
class EncoderGlitch:
    """A bad encoder reading at the sample nearest ``time_s``.

    kind ``spike``: that one reading of ``axis`` is off by ``offset_m``.
    kind ``hold``: from that sample on, the readings of both axes repeat the
    previous one for ``samples`` samples (a missed read of the interface card).
    """

    kind: Literal["spike", "hold"]
    time_s: TimeS
    axis: Axis = "x"
    offset_m: SpikeOffset = 50.0e-6
    samples: HoldSamples = 1

    def __post_init__(self) -> None:
        if self.kind == "spike" and self.offset_m == 0.0:
            raise rule(
                "offset_m",
                f"a spike must be nonzero, in [-{fmt(SPIKE_OFFSET_MAX_M)}, {fmt(SPIKE_OFFSET_MAX_M)}] m, got 0",
            )


@validated("velocity_noise")
class VelocityNoise:
    """Extra Gaussian noise on the measured velocity from ``start_s`` to ``end_s``.

    std_m_s: standard deviation per axis (X, Y), m/s. seed: the numpy
    Generator seed, so a run is reproducible.
    """

    std_m_s: VelocityNoiseStd
    seed: Seed = 0
    start_s: TimeS = 0.0
    end_s: TimeS = TIME_MAX_S

    def __post_init__(self) -> None:
        _after(self.start_s, self.end_s)


@validated("")
class PlantChanges:
    """Everything that changes in the plant or the sensor during one run.

    At most one friction drift per axis and quantity (viscous, Coulomb), one
    cogging ripple per axis, and payload changes at distinct times.
    """

    friction_drift: tuple[FrictionDrift, ...] = ()
    payload_change: tuple[PayloadChange, ...] = ()
    cogging: tuple[CoggingRipple, ...] = ()
    encoder_glitch: tuple[EncoderGlitch, ...] = ()
    velocity_noise: VelocityNoise | None = None

    def __post_init__(self) -> None:
        seen: set[tuple[str, str]] = set()
        for i, drift in enumerate(self.friction_drift):
            for quantity, moved in (("viscous", drift.viscous_to_v_s_m), ("coulomb", drift.coulomb_to_v)):
                if moved is None:
                    continue
                if (drift.axis, quantity) in seen:
                    raise rule(
                        f"friction_drift[{i}].axis",
                        f"{quantity} friction of axis {drift.axis} already "
                        "drifts in an earlier entry (one drift per axis and quantity)",
                    )
                seen.add((drift.axis, quantity))
        times = [c.time_s for c in self.payload_change]
        if len(set(times)) != len(times):
            raise rule("payload_change.time_s", f"must be distinct, got {times}")
        axes = [c.axis for c in self.cogging]
        if len(set(axes)) != len(axes):
            raise rule("cogging.axis", f"at most one ripple per axis (x, y), got {axes}")

    @property
    def empty(self) -> bool:
        return not (
            self.friction_drift or self.payload_change or self.cogging or self.encoder_glitch or self.velocity_noise
        )

    # ---- schedules over the run's sample times t (N,) -------------------------------------

    def _friction_v(self, plant: Plant, t: np.ndarray, coulomb: bool) -> np.ndarray:
        """The model's viscous (B) or Coulomb (Af; LuGre: Fc) level at each sample, volts, (N, 2)."""
        gear = plant.gear_n_per_v
        own = (plant.model.dof_frictionloss if coulomb else plant.model.dof_damping)[plant.dof_index] / gear
        for axis, actuator in enumerate(plant.friction_index):
            if coulomb and actuator >= 0:
                own[axis] = plant.model.actuator_biasprm[actuator, 3] / gear[axis]
        out = np.tile(own, (t.size, 1))
        for drift in self.friction_drift:
            to = drift.coulomb_to_v if coulomb else drift.viscous_to_v_s_m
            if to is None:
                continue
            start = drift.coulomb_from_v if coulomb else drift.viscous_from_v_s_m
            a = drift.axis_index
            out[:, a] = _ramp(t, drift.start_s, drift.end_s, own[a] if start is None else start, to)
        return out

    def damping_n_s_m(self, plant: Plant, t: np.ndarray) -> np.ndarray:
        """Joint damping (X, Y) at each sample, N s/m (= B volts * gear), shape (N, 2)."""
        return self._friction_v(plant, np.asarray(t, dtype=float), coulomb=False) * plant.gear_n_per_v

    def frictionloss_n(self, plant: Plant, t: np.ndarray) -> np.ndarray:
        """Joint Coulomb level (X, Y) at each sample, N (= Af volts * gear), shape (N, 2)."""
        return self._friction_v(plant, np.asarray(t, dtype=float), coulomb=True) * plant.gear_n_per_v

    def payload_mass_kg(self, plant: Plant, t: np.ndarray) -> np.ndarray:
        """Payload mass on the X carriage at each sample, kg, shape (N,).

        The plant's own payload until the first change; each change holds from
        its time (inclusive) to the next.
        """
        t = np.asarray(t, dtype=float)
        mass = np.full(t.size, float(plant.payload.mass_kg))
        for change in sorted(self.payload_change, key=lambda c: c.time_s):
            mass[t >= change.time_s] = change.mass_kg
        return mass

    def position_offset_m(self, t: np.ndarray) -> np.ndarray:
        """Offset added to the encoder reading (X, Y) at each sample (spikes), m, shape (N, 2)."""
        t = np.asarray(t, dtype=float)
        out = np.zeros((t.size, 2))
        for glitch in self.encoder_glitch:
            k = _sample_at(t, glitch.time_s)
            if glitch.kind == "spike" and k is not None:
                out[k, AXES.index(glitch.axis)] += glitch.offset_m
        return out

    def hold_mask(self, t: np.ndarray) -> np.ndarray:
        """True where the encoder repeats its previous reading (both axes), shape (N,)."""
        t = np.asarray(t, dtype=float)
        out = np.zeros(t.size, dtype=bool)
        for glitch in self.encoder_glitch:
            k = _sample_at(t, glitch.time_s)
            if glitch.kind == "hold" and k is not None:
                out[k : k + glitch.samples] = True
        return out

    def velocity_noise_m_s(self, t: np.ndarray) -> np.ndarray:
        """Extra noise on the measured velocity (X, Y), m/s, shape (N, 2); deterministic per seed."""
        t = np.asarray(t, dtype=float)
        noise = self.velocity_noise
        if noise is None:
            return np.zeros((t.size, 2))
        draws = np.random.default_rng(noise.seed).standard_normal((t.size, 2))
        active = (t >= noise.start_s) & (t < noise.end_s)
        return draws * np.asarray(noise.std_m_s) * active[:, None]

    def cogging_table(self) -> np.ndarray:
        """(2, 3) per axis X, Y: amplitude V, pitch m, phase rad (amplitude 0: no ripple), for :func:`cogging_force`."""
        table = np.zeros((2, 3))
        table[:, 1] = 1.0
        for ripple in self.cogging:
            table[ripple.axis_index] = (ripple.amplitude_v, ripple.pitch_m, ripple.phase_rad)
        return table

    def cogging_force_v(self, q_m: np.ndarray) -> np.ndarray:
        """Cogging force (X, Y) at position q (m), volts: amplitude sin(2 pi q / pitch + phase)."""
        q = np.asarray(q_m, dtype=float)
        table, force = self.cogging_table(), reference(cogging_force)
        return np.array([force(table, axis, float(q[axis])) for axis in range(2)])

    def true_parameters_over_time(
        self, plant: Plant, t: np.ndarray, operating_point_m: tuple[float, float] | np.ndarray = (0.0, 0.0)
    ) -> np.ndarray:
        """The true theta [M1, M2, B1, B2, Af1, Af2, dN1, dN2] at each sample, volt units, (N, 8).

        Masses: the model's moving masses without the payload plus the payload
        schedule (a payload on the X carriage adds its mass to both slide
        joints); B and Af from the drift schedules; dN the plant's static input
        offset at the operating point (:meth:`Plant.offset_v`; cogging is an
        unmodelled, zero-mean disturbance, not a parameter).
        """
        t = np.asarray(t, dtype=float)
        gear = plant.gear_n_per_v
        bare_kg = moving_masses_kg(plant.model, plant.dof_index) - plant.payload.mass_kg
        mass_v = (bare_kg[None, :] + self.payload_mass_kg(plant, t)[:, None]) / gear
        viscous, coulomb = self._friction_v(plant, t, coulomb=False), self._friction_v(plant, t, coulomb=True)
        for axis, actuator in enumerate(plant.friction_index):
            if actuator >= 0:
                p = lugre_parameters(plant.model, int(actuator), int(plant.dof_index[axis]))
                fc = coulomb[:, axis] * gear[axis]
                af, b = identified_af_b(fc, fc * p.fs_n / p.fc_n, p.vs_m_s, viscous[:, axis] * gear[axis])
                coulomb[:, axis], viscous[:, axis] = af / gear[axis], b / gear[axis]
        offset = np.tile(plant.offset_v(operating_point_m), (t.size, 1))
        return np.column_stack([mass_v, viscous, coulomb, offset])


# ---- what the loop applies each sample (both backends) -------------------------------------


@kernel(inline=True)
def cogging_force(table, axis, q_m):
    """Cogging force of one axis at the true position q_m, volts; table from PlantChanges.cogging_table."""
    if table[axis, 0] == 0.0:
        return 0.0
    return table[axis, 0] * math.sin(2.0 * math.pi * q_m / table[axis, 1] + table[axis, 2])


class ChangeSchedule(NamedTuple):
    """Per-sample plant and sensor changes for the loop, over the run's N samples.

    The first four are views of mjModel memory the loop writes into. Each
    schedule is (N, ...) when the run has that kind of change, else empty
    (0, ...), which the loop reads as "unchanged". friction_actuator (2,):
    each axis' LuGre actuator (-1: Coulomb friction), stribeck_ratio (2,) its
    Fs / Fc. cogging (2, 3): see :meth:`PlantChanges.cogging_table`. none: an
    empty (0,) array, the sensor's "no glitch".
    """

    dof_damping: np.ndarray
    dof_frictionloss: np.ndarray
    body_mass: np.ndarray
    actuator_biasprm: np.ndarray
    friction_actuator: np.ndarray
    stribeck_ratio: np.ndarray
    payload_body: int
    damping_n_s_m: np.ndarray
    frictionloss_n: np.ndarray
    payload_kg: np.ndarray
    cogging: np.ndarray
    offset_m: np.ndarray
    hold: np.ndarray
    velocity_noise_m_s: np.ndarray
    none: np.ndarray


def change_schedule(plant: Plant, changes: PlantChanges | None, t: np.ndarray) -> ChangeSchedule:
    """The loop's per-sample arrays for ``changes`` over the sample times t (N,) s."""
    model = plant.model
    none2, none1 = np.empty((0, 2)), np.empty(0)
    changes = changes or PlantChanges()
    body = -1
    if changes.payload_change:
        if plant.payload_body_id is None:
            raise ValueError(
                "changes.payload_change: the plant has no payload body to change; build it with "
                "Plant(payload, payload_body=True)"
            )
        body = plant.payload_body_id
    glitches = changes.encoder_glitch
    actuators = np.ascontiguousarray(plant.friction_index, dtype=np.int64)
    ratio = np.array(
        [model.actuator_biasprm[a, 4] / model.actuator_biasprm[a, 3] if a >= 0 else 1.0 for a in actuators]
    )
    return ChangeSchedule(
        model.dof_damping,
        model.dof_frictionloss,
        model.body_mass,
        model.actuator_biasprm,
        actuators,
        ratio,
        body,
        np.ascontiguousarray(changes.damping_n_s_m(plant, t)) if changes.friction_drift else none2,
        np.ascontiguousarray(changes.frictionloss_n(plant, t)) if changes.friction_drift else none2,
        np.ascontiguousarray(changes.payload_mass_kg(plant, t)) if changes.payload_change else none1,
        changes.cogging_table(),
        np.ascontiguousarray(changes.position_offset_m(t)) if any(g.kind == "spike" for g in glitches) else none2,
        np.ascontiguousarray(changes.hold_mask(t))
        if any(g.kind == "hold" for g in glitches)
        else np.empty(0, dtype=np.bool_),
        np.ascontiguousarray(changes.velocity_noise_m_s(t)) if changes.velocity_noise is not None else none2,
        none1,
    )


@kernel(inline=True)
def apply_plant_changes(dof_index, changes, k):
    """Write sample k's scheduled joint damping, Coulomb level and payload mass into the model.

    The Coulomb level of a LuGre axis is its actuator's Fc (biasprm[3]), with
    Fs (biasprm[4]) at the same ratio to it.

    Only body_mass changes; MuJoCo derives the mass matrix from it at every
    step. dof_invweight0 (set at compile time, used to scale constraint
    regularisation) keeps its unloaded value: with this model's stiff friction
    that changes nothing measurable (tests/test_faults_loop.py compares with a
    plant compiled with the payload).
    """
    if changes.damping_n_s_m.shape[0] > 0:
        for i in range(2):
            changes.dof_damping[dof_index[i]] = changes.damping_n_s_m[k, i]
            actuator = changes.friction_actuator[i]
            if actuator >= 0:
                changes.actuator_biasprm[actuator, 3] = changes.frictionloss_n[k, i]
                changes.actuator_biasprm[actuator, 4] = changes.frictionloss_n[k, i] * changes.stribeck_ratio[i]
            else:
                changes.dof_frictionloss[dof_index[i]] = changes.frictionloss_n[k, i]
    if changes.payload_kg.shape[0] > 0:
        changes.body_mass[changes.payload_body] = changes.payload_kg[k]


@kernel(inline=True)
def sensor_glitches(changes, k):
    """Sample k's encoder glitches: (offset m (2,) or empty, hold, velocity noise m/s (2,) or empty)."""
    offset = changes.offset_m[k] if changes.offset_m.shape[0] > 0 else changes.none
    noise = changes.velocity_noise_m_s[k] if changes.velocity_noise_m_s.shape[0] > 0 else changes.none
    hold = changes.hold.shape[0] > 0 and changes.hold[k]
    return offset, hold, noise


__all__ = [
    "CoggingRipple",
    "EncoderGlitch",
    "FrictionDrift",
    "PayloadChange",
    "PlantChanges",
    "VelocityNoise",
    "change_schedule",
    "cogging_force",
]
