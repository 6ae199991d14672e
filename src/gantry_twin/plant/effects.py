"""The plant's properties beyond the rigid body: a static input offset and a force ripple per axis, and
the MJCF numerics that carry them and the rig's LuGre friction (models/rig.xml; docs/rig-plant.md); the
amplifier between the DAC and the motor force: a computation delay and a first-order current loop
(:class:`Amplifier`, docs/equations.md "The amplifier").

The offset and the ripple act through the disturbance motors at the true
position, every sample (:func:`plant_input_v`); the amplifier acts on the
control motors' input (:func:`amplifier_output`). The controller never sees them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import mujoco
import numpy as np

from gantry_twin.numerics.jit import kernel
from gantry_twin.plant.friction import Friction, LuGreAxis
from gantry_twin.settings import Count, Range, fmt, rule, validated
from gantry_twin.theta import AXES

# ---------------------------------------------------------------------------
# The rig's input offset and force ripple (docs/rig-plant.md).

#: Largest static input offset per axis, V (about 10 N at kf = 69 N/V: a cable carrier's drag, a tilt,
#: an amplifier offset), and largest change of its linear part over the half travel, V.
OFFSET_MAX_V = 0.15
OFFSET_HALF_TRAVEL_MAX_V = 0.1
#: The half travel, m (the joints' range +-255 mm in models/gantry.xml).
HALF_TRAVEL_M = 0.255
#: Largest peak of a force ripple per axis (the sum of its harmonics' amplitudes), V; harmonics per axis.
RIPPLE_MAX_V = 0.1
RIPPLE_HARMONICS = 3
#: Columns of :func:`input_table`: offset V, slope V/m, pitch m, then (amplitude V, phase rad) per harmonic.
INPUT_COLUMNS = 3 + 2 * RIPPLE_HARMONICS


@validated("offset")
class OffsetAxis:
    """One axis' static input offset, dN(q) = constant_v + half_travel_v q / HALF_TRAVEL_M, volts.

    The paper's dN (eq. (1), theta 7-8) is a constant; ``half_travel_v`` is
    the change over the half travel of a part linear in position (a cable
    carrier's spring), 0 by default. Positive dN pushes the axis forward, as
    a positive input does.
    """

    constant_v: Range(-OFFSET_MAX_V, OFFSET_MAX_V, "V") = 0.0
    half_travel_v: Range(-OFFSET_HALF_TRAVEL_MAX_V, OFFSET_HALF_TRAVEL_MAX_V, "V") = 0.0

    @property
    def slope_v_m(self) -> float:
        """d dN / dq, V/m."""
        return self.half_travel_v / HALF_TRAVEL_M

    def at_v(self, q_m: float) -> float:
        """dN at position q (m), volts."""
        return self.constant_v + self.slope_v_m * q_m


@validated("offset")
class InputOffset:
    """The static input offset of each axis (:class:`OffsetAxis`)."""

    x: OffsetAxis = OffsetAxis()
    y: OffsetAxis = OffsetAxis()


@validated("harmonic")
class RippleHarmonic:
    """One harmonic of a force ripple: amplitude_v sin(2 pi k q / pitch + phase_rad), k its order (1, 2, 3)."""

    amplitude_v: Range(0.0, RIPPLE_MAX_V, "V")
    phase_rad: Range(-2.0 * math.pi, 2.0 * math.pi, "rad") = 0.0


@validated("ripple")
class RippleAxis:
    """One axis' force ripple: sum over the harmonics k = 1, 2, 3 of a_k sin(2 pi k q / pitch_m + phi_k), volts.

    pitch_m: the period in position of the first harmonic (an iron-core
    linear motor's magnet pitch). The peak (the sum of the amplitudes) is at
    most RIPPLE_MAX_V.
    """

    pitch_m: Range(1.0e-3, 1.0, "m") = 0.016
    harmonics: tuple[RippleHarmonic, ...] = ()

    def __post_init__(self) -> None:
        if len(self.harmonics) > RIPPLE_HARMONICS:
            raise rule("harmonics", f"at most {RIPPLE_HARMONICS} harmonics, got {len(self.harmonics)}")
        peak = sum(h.amplitude_v for h in self.harmonics)
        if peak > RIPPLE_MAX_V:
            raise rule("harmonics", f"the sum of the amplitudes must be at most {fmt(RIPPLE_MAX_V)} V, got {fmt(peak)}")

    def at_v(self, q_m: float) -> float:
        """The ripple at position q (m), volts."""
        w = 2.0 * math.pi * q_m / self.pitch_m
        return sum(h.amplitude_v * math.sin((k + 1) * w + h.phase_rad) for k, h in enumerate(self.harmonics))


@validated("ripple")
class ForceRipple:
    """The force ripple of each axis (:class:`RippleAxis`)."""

    x: RippleAxis = RippleAxis()
    y: RippleAxis = RippleAxis()


def input_table(offset: InputOffset, ripple: ForceRipple) -> np.ndarray:
    """(2, INPUT_COLUMNS) per axis X, Y: offset V, slope V/m, pitch m, (amplitude V, phase rad) x 3, for
    :func:`plant_input_v`."""
    table = np.zeros((2, INPUT_COLUMNS))
    for axis, name in enumerate(AXES):
        o, r = getattr(offset, name), getattr(ripple, name)
        table[axis, 0:3] = (o.constant_v, o.slope_v_m, r.pitch_m)
        for k, h in enumerate(r.harmonics):
            table[axis, 3 + 2 * k : 5 + 2 * k] = (h.amplitude_v, h.phase_rad)
    return table


@kernel(inline=True)
def plant_input_v(table, axis, q_m):
    """The plant's own input of one axis at the true position q_m, volts: dN(q) (:class:`OffsetAxis`) plus the
    force ripple (:class:`RippleAxis`); table from :func:`input_table`."""
    out = table[axis, 0] + table[axis, 1] * q_m
    w = 2.0 * math.pi * q_m / table[axis, 2]
    for k in range(RIPPLE_HARMONICS):
        amplitude = table[axis, 3 + 2 * k]
        if amplitude != 0.0:
            out += amplitude * math.sin((k + 1) * w + table[axis, 4 + 2 * k])
    return out


# ---- the amplifier: computation delay and current loop (docs/equations.md, "The amplifier") -----------

#: Largest computation delay, control samples (2 ms at Ts = 0.2 ms), and largest current-loop time constant, s.
DELAY_MAX_SAMPLES = 10
CURRENT_TAU_MAX_S = 0.01


@validated("amplifier")
class Amplifier:
    """What lies between the controller's command and the motor force, both off by default.

    delay_samples: the command computed from the measurement of sample k
    reaches the motor at sample k + n (the loop's own is n = 0: the command
    acts during the sample it was computed in). current_tau_s: the time
    constant of the amplifier's current loop, a first-order lag from the
    command to the force (0: none), sampled exactly: i(k) = i(k-1) +
    (1 - exp(-Ts / tau)) (u(k - n) - i(k-1)), held during sample k (the
    current at the end of the sample; a unit step from rest gives
    1 - exp(-(k + 1) Ts / tau)). Both start from 0 V. Typical values (a DSP
    board that computes within one sample; an amplifier's current loop of
    about 1-2 kHz bandwidth, tau 0.1-0.2 ms), not the rig's measured ones.
    """

    delay_samples: Count(0, DELAY_MAX_SAMPLES) = 0
    current_tau_s: Range(0.0, CURRENT_TAU_MAX_S, "s") = 0.0

    def current_gain(self, timestep_s: float) -> float:
        """1 - exp(-Ts / tau) per sample of Ts s; 1 (the command itself) without a current loop."""
        return 1.0 if self.current_tau_s == 0.0 else -math.expm1(-timestep_s / self.current_tau_s)

    def state(self) -> np.ndarray:
        """The amplifier's state, (delay_samples + 1, 2), zero: the pending commands, newest first, then the
        current, V."""
        return np.zeros((self.delay_samples + 1, 2))


@kernel(inline=True)
def amplifier_output(delay, gain, state, axis, u_v):
    """The motor input of one axis this sample, V, for the clipped command ``u_v``: the command of ``delay``
    samples ago through the current loop of gain 1 - exp(-Ts / tau) (:class:`Amplifier`); updates ``state``.

    With delay 0 and gain 1 it returns ``u_v`` itself (the loop as it is without an amplifier).
    """
    out = u_v
    if delay > 0:
        out = state[delay - 1, axis]
        for r in range(delay - 1, 0, -1):
            state[r, axis] = state[r - 1, axis]
        state[0, axis] = u_v
    if gain < 1.0:
        out = state[delay, axis] + gain * (out - state[delay, axis])
        state[delay, axis] = out
    return out


# ---- the rig's numerics in an MJCF file (models/rig.xml) -----------------------------------

#: Names of the <custom> numerics a model file may carry, per axis (docs/rig-plant.md):
#: lugre "sigma0 sigma1 Fc Fs vs" (N/m, N s/m, N, N, m/s), viscous "sigma2" (N s/m),
#: input_offset "constant_v half_travel_v", force_ripple "pitch_m a1 phi1 [a2 phi2 [a3 phi3]]".
NUMERIC = {
    "lugre": "{axis}_lugre",
    "viscous": "{axis}_viscous",
    "input_offset": "{axis}_input_offset",
    "force_ripple": "{axis}_force_ripple",
}


class FileProperties(NamedTuple):
    """The plant properties an MJCF file's numerics give (None: the file has none of that kind)."""

    friction: Friction | None
    offset: InputOffset | None
    ripple: ForceRipple | None


def file_properties(spec: mujoco.MjSpec) -> FileProperties:
    """Read the numerics of :data:`NUMERIC` from a spec; each kind is given for both axes or for none.

    Raises ValueError naming the numeric when one is malformed or out of its range.
    """
    given = {name: {n.name: list(n.data) for n in spec.numerics}.get(name) for name in _numeric_names()}

    def values(kind: str) -> dict[str, list[float]] | None:
        found = {a: given[NUMERIC[kind].format(axis=a)] for a in AXES}
        if all(v is None for v in found.values()):
            return None
        missing = [NUMERIC[kind].format(axis=a) for a, v in found.items() if v is None]
        if missing:
            raise ValueError(f"numeric {missing[0]}: missing (a plant property is given for both axes or neither)")
        return found

    friction = offset = ripple = None
    lugre, viscous = values("lugre"), values("viscous")
    if lugre is not None:
        axes = {}
        for a, p in lugre.items():
            _count(NUMERIC["lugre"].format(axis=a), p, 5, 5)
            sigma2 = None if viscous is None else _count(NUMERIC["viscous"].format(axis=a), viscous[a], 1, 1)[0]
            axes[a] = LuGreAxis(*p, sigma2_ns_m=sigma2)
        friction = Friction(model="lugre", **axes)
    elif viscous is not None:
        raise ValueError(f"numeric {NUMERIC['viscous'].format(axis='x')}: given without {NUMERIC['lugre']}")
    found = values("input_offset")
    if found is not None:
        offset = InputOffset(
            **{a: OffsetAxis(*_count(NUMERIC["input_offset"].format(axis=a), p, 1, 2)) for a, p in found.items()}
        )
    found = values("force_ripple")
    if found is not None:
        axes = {}
        for a, p in found.items():
            name = NUMERIC["force_ripple"].format(axis=a)
            _count(name, p, 1, 1 + 2 * RIPPLE_HARMONICS)
            if len(p) % 2 != 1:
                raise ValueError(f"numeric {name}: pitch_m then (amplitude_v, phase_rad) pairs, got {len(p)} values")
            pairs = [RippleHarmonic(p[i], p[i + 1]) for i in range(1, len(p), 2)]
            axes[a] = RippleAxis(pitch_m=p[0], harmonics=tuple(pairs))
        ripple = ForceRipple(**axes)
    return FileProperties(friction, offset, ripple)


def _numeric_names() -> list[str]:
    return [template.format(axis=a) for template in NUMERIC.values() for a in AXES]


def _count(name: str, values: list[float], lo: int, hi: int) -> list[float]:
    if not lo <= len(values) <= hi:
        want = str(lo) if lo == hi else f"{lo} to {hi}"
        raise ValueError(f"numeric {name}: {want} values, got {len(values)}")
    return values
