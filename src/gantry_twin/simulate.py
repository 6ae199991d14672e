"""The 0.2 ms loop: measure -> control -> disturb -> mj_step -> record.

One physics step per controller sample (Ts = the model's timestep, 0.2 ms).
The command is computed from that sample's measurement and held over the
step (zero-order hold, as the DS1103's DAC does). The disturbance actuators
are driven from the scenario's timeline; the controller never sees them.

The loop records into a :class:`Trace` preallocated for the whole run and
hands it to observers (progress bars, live telemetry, pacing) after every
chunk of ``chunk_s`` simulated seconds. Observers only read the trace:
nothing they do changes the simulation.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import mujoco
import numpy as np

from gantry_twin.controllers.base import Controller, Measurement, ReferenceSample, RunContext
from gantry_twin.paths import Path, Reference, TimingLaw, contour_error, reference
from gantry_twin.plant import Plant
from gantry_twin.sensing import Encoder, SensingConfig
from gantry_twin.taskframe import task_errors

#: A disturbance timeline: times (N,) s -> input disturbance (N, 2) volts.
Disturbance = Callable[[np.ndarray], np.ndarray]


class SimulationError(RuntimeError):
    """The run cannot go on (a non-finite measurement or command)."""


@dataclass
class Trace:
    """Everything a run produced, one row per 0.2 ms sample (SI units).

    t_s (N,); q_m true position, q_meas_m measured, q_d_m desired, e_m = q - q_d
    (N, 2); eps_n_m, eps_c_m (N,) approximate and true contouring error;
    u_v command, disturbance_v input disturbance (N, 2) volts;
    controller_state: what ``state_for_logging`` returned, stacked over time
    (DIARC: theta_hat (N, 8), dc_hat (N, 2), gamma_diag (N, 8),
    gamma_lambda_max (N,)); true_theta (8,) volt units from the model.
    ``filled``: how many samples hold data (all of them after the run).
    """

    t_s: np.ndarray
    q_m: np.ndarray
    q_meas_m: np.ndarray
    q_d_m: np.ndarray
    e_m: np.ndarray
    eps_n_m: np.ndarray
    eps_c_m: np.ndarray
    u_v: np.ndarray
    disturbance_v: np.ndarray
    true_theta: np.ndarray
    controller_state: dict[str, np.ndarray] = field(default_factory=dict)
    filled: int = 0

    @classmethod
    def allocate(cls, ref: Reference, disturbance_v: np.ndarray, true_theta: np.ndarray) -> Trace:
        n = ref.t_s.size
        nan2 = np.full((n, 2), np.nan)
        return cls(
            t_s=ref.t_s,
            q_m=nan2.copy(),
            q_meas_m=nan2.copy(),
            q_d_m=ref.q_d,
            e_m=nan2.copy(),
            eps_n_m=np.full(n, np.nan),
            eps_c_m=np.full(n, np.nan),
            u_v=nan2.copy(),
            disturbance_v=disturbance_v,
            true_theta=true_theta,
        )

    @property
    def sample_period_s(self) -> float:
        return float(self.t_s[1] - self.t_s[0]) if self.t_s.size > 1 else 0.0

    def record_state(self, k: int, state: dict[str, np.ndarray]) -> None:
        """Store one sample of the controller's logged state."""
        buffers = self.controller_state
        for key, value in state.items():
            value = np.asarray(value, dtype=float)
            if key not in buffers:
                n = self.t_s.size
                buffers[key] = np.full((n,) if value.size == 1 else (n, *value.shape), np.nan)
            buffers[key][k] = value.reshape(buffers[key][k].shape)


@dataclass(frozen=True)
class RunInfo:
    """What observers learn before the first sample."""

    plant: Plant
    path: Path
    timing: TimingLaw
    reference: Reference
    duration_s: float
    controller_name: str


class Observer(Protocol):
    """Watches a run chunk by chunk; must not change the trace."""

    def on_start(self, run: RunInfo, trace: Trace) -> None: ...

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None: ...

    def on_end(self, trace: Trace) -> None: ...


def _finish_chunk(trace: Trace, ref: Reference, path: Path, start: int, stop: int) -> None:
    """Derived errors for samples [start, stop): e, eps_n and the true eps_c."""
    e = trace.q_m[start:stop] - ref.q_d[start:stop]
    trace.e_m[start:stop] = e
    trace.eps_n_m[start:stop] = task_errors(ref.alpha[start:stop], e)[:, 0]
    trace.eps_c_m[start:stop], _ = contour_error(path, trace.q_m[start:stop], ref.phi[start:stop])
    trace.filled = stop


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
) -> Trace:
    """Run the closed loop for ``duration_s`` seconds and return the trace.

    The plant starts at q_d(0) moving at q_d'(0): for an ``on_path`` timing
    law that is the paper's "already running" start; for ``rest``, standstill.
    """
    sensing = sensing or SensingConfig()
    ts = plant.timestep_s
    n = int(round(duration_s / ts))
    if n < 2:
        raise ValueError(f"duration_s must hold at least two samples of {ts} s, got {duration_s}")
    t = np.arange(n) * ts
    ref = reference(path, timing, t)
    rows = ref.packed()
    dist = np.zeros((n, 2)) if disturbance is None else np.asarray(disturbance(t), dtype=float)
    if dist.shape != (n, 2):
        raise ValueError(f"disturbance must give shape ({n}, 2) volts, got {dist.shape}")

    model, data = plant.model, plant.data
    plant.reset(ref.q_d[0], ref.dq_d[0])
    encoder = Encoder(sensing, ts)
    encoder.reset(plant.q_m, plant.dq_m_s)
    trace = Trace.allocate(ref, dist, plant.true_parameters())
    u_max = plant.ctrl_range_v[:, 1]
    motors, dist_act = plant.motor_index, plant.disturbance_index
    info = RunInfo(plant, path, timing, ref, duration_s, controller_name or type(controller).__name__)
    for observer in observers:
        observer.on_start(info, trace)

    chunk = max(1, int(round(chunk_s / ts)))
    for start in range(0, n, chunk):
        stop = min(n, start + chunk)
        for k in range(start, stop):
            q_true = plant.q_m.copy()
            position, velocity = encoder.measure(q_true, plant.dq_m_s)
            if not (np.isfinite(position).all() and np.isfinite(velocity).all()):
                raise SimulationError(f"non-finite measurement at t = {t[k]:.4f} s: q = {position}, q' = {velocity}")
            measurement = Measurement(float(t[k]), position, velocity)
            if k == 0:
                controller.reset(RunContext(ts, u_max.copy(), measurement))
            command = np.asarray(controller.update(measurement, ReferenceSample.from_row(rows[k])), dtype=float)
            if command.shape != (2,) or not np.isfinite(command).all():
                raise SimulationError(f"controller returned {command!r} at t = {t[k]:.4f} s; expected 2 finite volts")
            u = np.clip(command, -u_max, u_max)
            trace.q_m[k] = q_true
            trace.q_meas_m[k] = position
            trace.u_v[k] = u
            trace.record_state(k, controller.state_for_logging())
            data.ctrl[motors] = u
            data.ctrl[dist_act] = dist[k]
            mujoco.mj_step(model, data)
        _finish_chunk(trace, ref, path, start, stop)
        for observer in observers:
            observer.on_chunk(trace, start, stop)
    for observer in observers:
        observer.on_end(trace)
    return trace
