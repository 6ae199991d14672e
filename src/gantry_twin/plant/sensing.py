"""What the DS1103 sees: quantised encoder positions and velocity by difference.

The sensing (docs/equations.md): linear encoders of 0.5 um resolution,
sampled every Ts = 0.2 ms; velocity is the backward difference of
consecutive quantised positions (resolution 0.5 um / 0.2 ms = 2.5 mm/s).
Each can be switched off for ideal sensing in tests.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from gantry_twin.numerics.jit import kernel, reference
from gantry_twin.settings import Range, validated

#: The Anorad gantry's encoder resolution after quadrature, metres.
ENCODER_RESOLUTION_M = 0.5e-6


@validated("sensing")
class SensingConfig:
    """How positions and velocities are measured.

    quantize: round each axis position to ``resolution_m`` (encoder counts).
    velocity_by_difference: velocity = (q_k - q_{k-1}) / Ts of the measured
    positions; if False the true joint velocity is used.
    """

    quantize: bool = True
    #: From 1 nm (the finest linear encoders; smaller steps round nothing and q / resolution overflows
    #: towards 1e-308) to 1 mm.
    resolution_m: Range(1e-9, 1e-3, "m") = ENCODER_RESOLUTION_M
    velocity_by_difference: bool = True

    @classmethod
    def ideal(cls) -> SensingConfig:
        """Exact positions and exact velocities."""
        return cls(quantize=False, velocity_by_difference=False)


@kernel(inline=True)
def quantized(q_m, resolution_m):
    """Encoder reading: the nearest multiple of the resolution (metres), ties to even."""
    return np.rint(q_m / resolution_m) * resolution_m


def quantize(q_m: np.ndarray, resolution_m: float) -> np.ndarray:
    """:func:`quantized` for numbers or arrays, run uncompiled (no compile on first use)."""
    return reference(quantized)(np.asarray(q_m, dtype=float), float(resolution_m))


class EncoderState(NamedTuple):
    """The encoder as the loop kernels see it: its settings and its memory previous_m (2,), metres."""

    quantize: bool
    resolution_m: float
    velocity_by_difference: bool
    sample_period_s: float
    previous_m: np.ndarray


@kernel(inline=True)
def encoder_read(encoder, q_m):
    """One axis's reading of the true position q_m, metres (quantised if the encoder counts)."""
    if encoder.quantize:
        return quantized(q_m, encoder.resolution_m)
    return q_m


@kernel(inline=True)
def encoder_measure(encoder, q_m, dq_m_s, offset_m, hold, velocity_noise_m_s, position, velocity):
    """Measured position m and velocity m/s (2,) from the true joint state, into position and velocity.

    Glitches (gantry_twin.plant.faults): ``offset_m`` (2,) is added to the reading
    (a spike); ``hold`` repeats the previous reading of both axes;
    ``velocity_noise_m_s`` (2,) is added to the velocity; pass an empty array
    (0,) for none (adding zeros would turn a reading of -0.0 into 0.0). A bad
    reading is remembered like a good one (the next difference uses it).
    Returns False if a value is not finite.
    """
    previous_m = encoder.previous_m
    spike, noise = offset_m.shape[0] > 0, velocity_noise_m_s.shape[0] > 0
    finite = True
    for i in range(2):
        position[i] = encoder_read(encoder, q_m[i])
        if spike:
            position[i] = position[i] + offset_m[i]
        if hold:
            position[i] = previous_m[i]
        if encoder.velocity_by_difference:
            velocity[i] = (position[i] - previous_m[i]) / encoder.sample_period_s
        else:
            velocity[i] = dq_m_s[i]
        if noise:
            velocity[i] = velocity[i] + velocity_noise_m_s[i]
        previous_m[i] = position[i]
        finite = finite and math.isfinite(position[i]) and math.isfinite(velocity[i])
    return finite


@kernel
def encoder_reset(encoder, q_m, dq_m_s):
    """Start as if the machine had been moving at dq_m_s before t = 0."""
    for i in range(2):
        encoder.previous_m[i] = encoder_read(encoder, q_m[i] - dq_m_s[i] * encoder.sample_period_s)


class Encoder:
    """Stateful sensor: remembers the previous reading for the difference.

    A thin wrapper around :func:`encoder_measure` (run uncompiled); the
    compiled loop runs the same kernel on :attr:`state`.
    """

    def __init__(self, config: SensingConfig, sample_period_s: float) -> None:
        self.config = config
        self.sample_period_s = sample_period_s
        self.state = EncoderState(
            bool(config.quantize),
            float(config.resolution_m),
            bool(config.velocity_by_difference),
            float(sample_period_s),
            np.zeros(2),
        )

    def reset(self, q_m: np.ndarray, dq_m_s: np.ndarray) -> None:
        """Start as if the machine had been moving at dq before t = 0."""
        reference(encoder_reset)(self.state, _vec(q_m), _vec(dq_m_s))

    def measure(
        self,
        q_m: np.ndarray,
        dq_m_s: np.ndarray,
        offset_m: np.ndarray | None = None,
        hold: bool = False,
        velocity_noise_m_s: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Measured (position m, velocity m/s) from the true joint state (see :func:`encoder_measure`)."""
        position, velocity = np.zeros(2), np.zeros(2)
        reference(encoder_measure)(
            self.state,
            _vec(q_m),
            _vec(dq_m_s),
            _NONE if offset_m is None else _vec(offset_m),
            bool(hold),
            _NONE if velocity_noise_m_s is None else _vec(velocity_noise_m_s),
            position,
            velocity,
        )
        return position, velocity


_NONE = np.zeros(0)


def _vec(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, dtype=float).reshape(2)
