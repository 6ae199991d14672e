"""What the DS1103 sees: quantised encoder positions and velocity by difference.

Control-spec section 2: linear encoders of 0.5 um resolution, sampled every
Ts = 0.2 ms; velocity is the backward difference of consecutive quantised
positions (resolution 0.5 um / 0.2 ms = 2.5 mm/s). Each can be switched off
for ideal sensing in tests.
"""

from __future__ import annotations

import numpy as np

from gantry_twin.ranges import Range, settings

#: The Anorad gantry's encoder resolution after quadrature, metres.
ENCODER_RESOLUTION_M = 0.5e-6


@settings("sensing")
class SensingConfig:
    """How positions and velocities are measured.

    quantize: round each axis position to ``resolution_m`` (encoder counts).
    velocity_by_difference: velocity = (q_k - q_{k-1}) / Ts of the measured
    positions; if False the true joint velocity is used.
    """

    quantize: bool = True
    resolution_m: Range(0.0, 1e-3, "m", lo_open=True) = ENCODER_RESOLUTION_M
    velocity_by_difference: bool = True

    @classmethod
    def ideal(cls) -> SensingConfig:
        """Exact positions and exact velocities."""
        return cls(quantize=False, velocity_by_difference=False)


def quantize(q_m: np.ndarray, resolution_m: float) -> np.ndarray:
    """Encoder reading: the nearest multiple of the resolution (metres)."""
    return np.round(q_m / resolution_m) * resolution_m


class Encoder:
    """Stateful sensor: remembers the previous reading for the difference."""

    def __init__(self, config: SensingConfig, sample_period_s: float) -> None:
        self.config = config
        self.sample_period_s = sample_period_s
        self._previous_m = np.zeros(2)

    def _read(self, q_m: np.ndarray) -> np.ndarray:
        if self.config.quantize:
            return quantize(q_m, self.config.resolution_m)
        return np.array(q_m, dtype=float)

    def reset(self, q_m: np.ndarray, dq_m_s: np.ndarray) -> None:
        """Start as if the machine had been moving at dq before t = 0."""
        self._previous_m = self._read(np.asarray(q_m) - np.asarray(dq_m_s) * self.sample_period_s)

    def measure(self, q_m: np.ndarray, dq_m_s: np.ndarray, offset_m: np.ndarray | None = None, hold: bool = False,
                velocity_noise_m_s: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Measured (position m, velocity m/s) from the true joint state.

        Glitches (gantry_twin.changes): ``offset_m`` (2,) is added to the
        reading (a spike); ``hold`` repeats the previous reading of both axes;
        ``velocity_noise_m_s`` (2,) is added to the velocity. A bad reading is
        remembered like a good one (the next difference uses it).
        """
        position = self._read(q_m)
        if offset_m is not None:
            position = position + offset_m
        if hold:
            position = self._previous_m.copy()
        if self.config.velocity_by_difference:
            velocity = (position - self._previous_m) / self.sample_period_s
        else:
            velocity = np.array(dq_m_s, dtype=float)
        if velocity_noise_m_s is not None:
            velocity = velocity + velocity_noise_m_s
        self._previous_m = position
        return position, velocity
