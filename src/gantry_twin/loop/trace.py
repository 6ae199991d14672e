"""What a run produces and who watches it: the trace, the run's context, observers.

Below the loop (:mod:`gantry_twin.loop.simulate`) so that everything downstream
(metrics, results, telemetry, the monitor) can read a trace without
importing the loop.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from gantry_twin.paths.contours import Contour, Reference, TimingLaw
from gantry_twin.plant.model import Plant


class SimulationError(RuntimeError):
    """The run cannot go on: a non-finite measurement or command, or the controller raised.

    time_s, step: the sample at which it stopped (None when it stopped before the first sample).
    trace: the samples before it (``trace.filled`` of them; the trace held last when the run was held in pieces).
    """

    def __init__(self, message: str, time_s: float | None = None, step: int | None = None) -> None:
        super().__init__(message)
        self.time_s, self.step = time_s, step
        self.trace: Trace | None = None


@dataclass
class Trace:
    """Everything a run produced, one row per 0.2 ms sample (SI units).

    t_s (N,); q_m true position, q_meas_m measured, q_d_m desired, e_m = q - q_d
    (N, 2); eps_n_m, eps_c_m (N,) approximate and true contouring error;
    u_v command, disturbance_v input disturbance (N, 2) volts;
    controller_state: what ``state_for_logging`` returned, stacked over time
    (DIARC: theta_hat (N, 8), dc_hat (N, 2), gamma_diag (N, 8),
    gamma_lambda_max (N,)); true_theta (8,) volt units from the model at t = 0.
    true_theta_t (N, 8): the true theta at each sample when the run's
    :class:`~gantry_twin.plant.faults.PlantChanges` move it (None otherwise: it is
    ``true_theta`` throughout; :meth:`true_parameters_t` gives it either way).
    ``filled``: how many samples of the run hold data (all of them after the run).

    A run held in pieces (``simulate(..., hold_s=...)``) gives observers a
    trace of one piece at a time: its arrays hold samples [first, first +
    len(t_s)) of the run, and observers index them with :meth:`rows`
    (``trace.eps_c_m[trace.rows(start, stop)]``), which is ``start:stop`` for
    a whole trace (``first`` = 0).
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
    true_theta_t: np.ndarray | None = None
    first: int = 0
    timestep_s: float | None = None

    def true_parameters_t(self) -> np.ndarray:
        """The true theta at each sample (N, 8), volt units (a read-only broadcast if nothing changes)."""
        if self.true_theta_t is not None:
            return self.true_theta_t
        return np.broadcast_to(self.true_theta, (self.t_s.size, 8))

    def rows(self, start: int, stop: int) -> slice:
        """Where samples [start, stop) of the run are in this trace's arrays."""
        return slice(start - self.first, stop - self.first)

    @classmethod
    def allocate(
        cls,
        ref: Reference,
        disturbance_v: np.ndarray,
        true_theta: np.ndarray,
        first: int = 0,
        timestep_s: float | None = None,
        full: Callable[[tuple[int, ...], float], np.ndarray] = np.full,
    ) -> Trace:
        """A trace of the samples of ``ref`` (samples [first, first + N) of the run), NaN until recorded;
        ``full(shape, value)`` makes each recorded array (numpy's, or one in memory shared with a worker)."""
        n = ref.t_s.size
        return cls(
            t_s=ref.t_s,
            q_m=full((n, 2), np.nan),
            q_meas_m=full((n, 2), np.nan),
            q_d_m=ref.q_d,
            e_m=full((n, 2), np.nan),
            eps_n_m=full((n,), np.nan),
            eps_c_m=full((n,), np.nan),
            u_v=full((n, 2), np.nan),
            disturbance_v=disturbance_v,
            true_theta=true_theta,
            filled=first,
            first=first,
            timestep_s=timestep_s,
        )

    @property
    def sample_period_s(self) -> float:
        if self.timestep_s is not None:
            return self.timestep_s
        return float(self.t_s[1] - self.t_s[0]) if self.t_s.size > 1 else 0.0

    def allocate_state(self, state: dict[str, np.ndarray]) -> None:
        """NaN buffers for each logged key not yet allocated, shaped like one sample of ``state``."""
        n = self.t_s.size
        for key, value in state.items():
            if key not in self.controller_state:
                value = np.asarray(value, dtype=float)
                self.controller_state[key] = np.full((n,) if value.size == 1 else (n, *value.shape), np.nan)

    def allocate_log(self, layout: tuple[tuple[str, tuple[int, ...]], ...]) -> np.ndarray:
        """One NaN buffer for a compiled controller's log; each key's array is a contiguous block of it.

        ``layout``: ((name, shape), ...) (shape () for one number, stored (N,)).
        The block of a key of size s starts at N times the sizes before it;
        sample k's values are at block + k s. Returns the flat buffer (N * total,).
        """
        n = self.t_s.size
        sizes = [int(np.prod(shape)) for _, shape in layout]
        buffer = np.full(n * sum(sizes), np.nan)
        at = 0
        for (name, shape), size in zip(layout, sizes, strict=True):
            self.controller_state[name] = buffer[at : at + n * size].reshape((n, *shape))
            at += n * size
        return buffer

    def record_state(self, k: int, state: dict[str, np.ndarray]) -> None:
        """Store one sample of the controller's logged state."""
        self.allocate_state(state)
        buffers = self.controller_state
        for key, value in state.items():
            buffers[key][k] = np.asarray(value, dtype=float).reshape(buffers[key][k].shape)


@dataclass(frozen=True)
class RunInfo:
    """What observers learn before the first sample.

    reference: the whole run's desired motion, or None when the run is held
    in pieces (compute what is needed with ``contours.reference(path, timing, t)``).
    samples: how many samples the run will have.
    """

    plant: Plant
    path: Contour
    timing: TimingLaw
    reference: Reference | None
    duration_s: float
    controller_name: str
    samples: int = 0


class Observer(Protocol):
    """Watches a run chunk by chunk; must not change the trace.

    ``on_chunk(trace, start, stop)``: samples [start, stop) of the run are
    recorded, at ``trace.rows(start, stop)``. ``on_end``: after the last
    sample, or after the samples before a fault (``trace.filled`` of them). In a run held in pieces a
    piece's samples are gone once its last chunk has been seen: an observer
    that batches must send what it holds back when ``stop`` reaches
    ``trace.first + trace.t_s.size``.
    """

    def on_start(self, run: RunInfo, trace: Trace) -> None: ...

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None: ...

    def on_end(self, trace: Trace) -> None: ...
