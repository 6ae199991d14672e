"""An industrial baseline: per-axis PD with velocity and acceleration feed-forward.

    u_i = -kp_i e_i - kd_i e_i' + kv_i x_d,i' + ka_i x_d,i''     (volts)

Default gains: kp = 10 000 V/m and kd = 100 V/(m/s) on both axes, the same
stiffness the ARC laws apply in the normal direction (Ks Lambda = 100 x 100);
feed-forward at the nominal no-load parameters, ka = M = (0.12, 0.5)
V/(m/s^2) and kv = B = (0.5, 0.7) V/(m/s). No friction compensation, no
adaptation and no coupling between the axes: what many machine builders
ship, and what the ARC laws are measured against.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gantry_twin.controllers.base import Measurement, ReferenceSample, RunContext


@dataclass
class PD:
    """Per-axis PD + feed-forward; all gains per axis (X, Y)."""

    kp_v_m: tuple[float, float] = (10000.0, 10000.0)
    kd_v_s_m: tuple[float, float] = (100.0, 100.0)
    kv_v_s_m: tuple[float, float] = (0.5, 0.7)
    ka_v_s2_m: tuple[float, float] = (0.12, 0.5)

    def __post_init__(self) -> None:
        self._u_max_v = np.full(2, 10.0)

    def reset(self, context: RunContext) -> None:
        self._u_max_v = np.asarray(context.u_max_v, dtype=float)

    def update(self, measurement: Measurement, reference: ReferenceSample) -> np.ndarray:
        e = measurement.q_m - reference.q_d
        de = measurement.dq_m_s - reference.dq_d
        u = (
            -np.asarray(self.kp_v_m) * e
            - np.asarray(self.kd_v_s_m) * de
            + np.asarray(self.kv_v_s_m) * reference.dq_d
            + np.asarray(self.ka_v_s2_m) * reference.ddq_d
        )
        return np.clip(u, -self._u_max_v, self._u_max_v)

    def state_for_logging(self) -> dict[str, np.ndarray]:
        return {}
