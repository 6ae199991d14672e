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
from typing import NamedTuple

import numpy as np

from gantry_twin.controllers.base import (
    REF_DDQ,
    REF_DQ,
    REF_Q,
    U_MAX_V,
    CompiledStep,
    Measurement,
    ReferenceSample,
    RunContext,
)
from gantry_twin.numerics.estimation import clip
from gantry_twin.numerics.jit import kernel
from gantry_twin.numerics.jit import reference as uncompiled
from gantry_twin.plant.model import AXES
from gantry_twin.settings import Range, Vector
from gantry_twin.theta import NOMINAL_THETA, per_axis

# A gain per axis (X, Y); the types of PD's fields are what a scenario's options accept. Upper bounds:
# kp and kd keep the discrete loop stable on the lightest axis (kd Ts / M1 < 2 with M1 = 0.12 V s^2/m:
# kd < 1200); kv and ka stay within a few times the heaviest machine the twin models (B up to 10
# V/(m/s) in `changes`, M2 = 0.79 V s^2/m with a 20 kg payload). Why: docs/scenarios.md.
Kp = Vector(Range(0.0, 1.0e5, "V/m"), AXES)
Kd = Vector(Range(0.0, 1000.0, "V/(m/s)"), AXES)
Kv = Vector(Range(0.0, 10.0, "V/(m/s)"), AXES)
Ka = Vector(Range(0.0, 2.0, "V/(m/s^2)"), AXES)


class PDParams(NamedTuple):
    """The gains (X, Y) as arrays, and the actuator limits u_max_v (2,) volts."""

    kp_v_m: np.ndarray
    kd_v_s_m: np.ndarray
    kv_v_s_m: np.ndarray
    ka_v_s2_m: np.ndarray
    u_max_v: np.ndarray


@kernel(nrt=False)
def pd_step(params, q_m, dq_m_s, ref, u_v):
    """u = clip(-kp e - kd e' + kv x_d' + ka x_d'') per axis, into u_v (2,) volts."""
    kp, kd, kv, ka, u_max = params
    for i in range(2):
        e = q_m[i] - ref[REF_Q + i]
        de = dq_m_s[i] - ref[REF_DQ + i]
        u = -kp[i] * e - kd[i] * de + kv[i] * ref[REF_DQ + i] + ka[i] * ref[REF_DDQ + i]
        u_v[i] = clip(u, -u_max[i], u_max[i])


@kernel(nrt=False)
def pd_command(params, state, t_s, q_m, dq_m_s, ref, u_v):
    """The compiled-controller step (controllers.base): :func:`pd_step`; PD has no state."""
    pd_step(params, q_m, dq_m_s, ref, u_v)


@dataclass
class PD:
    """Per-axis PD + feed-forward; all gains per axis (X, Y)."""

    kp_v_m: Kp = (10000.0, 10000.0)
    kd_v_s_m: Kd = (100.0, 100.0)
    kv_v_s_m: Kv = per_axis(NOMINAL_THETA, "B")
    ka_v_s2_m: Ka = per_axis(NOMINAL_THETA, "M")

    compiled = CompiledStep(pd_command)

    def __post_init__(self) -> None:
        self._u_max_v = np.array(U_MAX_V)

    def kernel_arguments(self) -> tuple[PDParams, tuple[()]]:
        """(params, state) for :func:`pd_command` (after ``reset``); PD has no state."""

        def arr(x: tuple[float, float]) -> np.ndarray:
            return np.asarray(x, dtype=float).copy()

        return PDParams(
            arr(self.kp_v_m), arr(self.kd_v_s_m), arr(self.kv_v_s_m), arr(self.ka_v_s2_m), self._u_max_v.copy()
        ), ()

    def reset(self, context: RunContext) -> None:
        self._u_max_v = np.asarray(context.u_max_v, dtype=float)

    def update(self, measurement: Measurement, reference: ReferenceSample) -> np.ndarray:
        u = np.zeros(2)
        params, _ = self.kernel_arguments()
        uncompiled(pd_step)(
            params,
            np.asarray(measurement.q_m, dtype=float),
            np.asarray(measurement.dq_m_s, dtype=float),
            reference.row(),
            u,
        )
        return u

    def state_for_logging(self) -> dict[str, np.ndarray]:
        return {}
