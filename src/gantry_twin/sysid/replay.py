"""How well an identified plant reproduces a log: replay the logged commands through it (docs/logs.md).

The logged u is applied open loop to the identified MJCF model (MuJoCo's
own dry friction, not the regression's), with the plant's own input (its
static offset and force ripple, :func:`gantry_twin.plant.effects.plant_input_v`,
at the measured position) in windows of ``window_s``, each
started from the measured state (the logged position, and the slope of a
local quadratic fit over ``VELOCITY_FIT_S`` around it, Savitzky-Golay: the
encoder's steps then leave micrometres per second of error): a whole log
replayed open loop drifts away with the first small force error (the
position integrates it), so only short windows say how well the model
predicts. All windows run at once in ``mujoco.rollout`` (MuJoCo's threaded
C loop). The residual is measured minus simulated position.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from gantry_twin.plant.effects import plant_input_v
from gantry_twin.plant.model import AXES, Plant
from gantry_twin.sysid.logs import Log

#: Default replay window, s.
WINDOW_S = 1.0
#: The span of the quadratic fit that gives each window's initial velocity, s.
VELOCITY_FIT_S = 0.01


@dataclass(frozen=True)
class Replay:
    """One log replayed: t_s (n,), measured and simulated positions (n, 2) m, NaN where no window covers."""

    path: str
    t_s: np.ndarray
    measured_m: np.ndarray
    simulated_m: np.ndarray
    window_s: float

    @property
    def residual_m(self) -> np.ndarray:
        return self.measured_m - self.simulated_m

    def rms_um(self) -> dict[str, float]:
        """rms of the residual per axis, um (over the samples the windows cover)."""
        r = self.residual_m
        return {a: float(np.sqrt(np.nanmean(r[:, i] ** 2)) * 1e6) for i, a in enumerate(AXES)}

    def max_um(self) -> dict[str, float]:
        r = self.residual_m
        return {a: float(np.nanmax(np.abs(r[:, i])) * 1e6) for i, a in enumerate(AXES)}


def replay(plant: Plant, log: Log, window_s: float = WINDOW_S) -> Replay:
    """Replay ``log``'s commands through ``plant`` in windows started from the measured state (module docstring)."""
    n = log.samples
    length = max(1, min(int(round(window_s / log.sample_period_s)), n - 1))
    half = max(1, int(round(0.5 * VELOCITY_FIT_S / log.sample_period_s)))
    starts = np.arange(half, n - 1 - half, length)
    if starts.size == 0:
        raise ValueError(f"{log.path}: too short to replay ({n} samples)")
    lengths = np.minimum(starts + length, n - 1) - starts
    qpos = replay_windows(plant, log, starts, length)
    simulated = np.full((n, 2), np.nan)
    for i, k in enumerate(starts):
        simulated[k + 1 : k + lengths[i] + 1] = qpos[i, : lengths[i]]
    return Replay(log.path, log.t_s, log.q_m, simulated, length * log.sample_period_s)


def replay_windows(plant: Plant, log: Log, starts: np.ndarray, length: int) -> np.ndarray:
    """Simulated positions (windows, length, 2), m, after each logged sample of the windows starting at ``starts``.

    Each window starts from the measured state at its start sample (module docstring; LuGre's bristle at its
    steady deflection, :meth:`Plant.reset`) and applies the logged u, held over the plant's physics sub-steps;
    commands past the log's end are zero. ``starts`` must leave VELOCITY_FIT_S / 2 of log on each side.
    """
    from mujoco import rollout
    from scipy.signal import savgol_coeffs

    model = plant.model
    sub = plant.substeps
    model.opt.timestep = log.sample_period_s / sub  # ``sub`` physics steps per logged sample (ZOH of u)
    n = log.samples
    half = max(1, int(round(0.5 * VELOCITY_FIT_S / log.sample_period_s)))
    slope = savgol_coeffs(2 * half + 1, 2, deriv=1, delta=log.sample_period_s, use="dot")
    data = mujoco.MjData(model)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    size = mujoco.mj_stateSize(model, spec)
    initial = np.empty((starts.size, size))
    for i, k in enumerate(starts):
        plant.reset(log.q_m[k], slope @ log.q_m[k - half : k + half + 1])
        mujoco.mj_getState(model, plant.data, initial[i], spec)
    control = np.zeros((starts.size, length, model.nu))
    table = plant.input_table()
    for i, k in enumerate(starts):
        stop = min(k + length, n - 1)
        control[i, : stop - k][:, plant.motor_index] = log.u_v[k:stop]
        for axis in range(len(AXES)):  # the plant's own input, offset and ripple, at the measured position
            q = log.q_m[k:stop, axis]
            control[i, : stop - k, plant.disturbance_index[axis]] = [plant_input_v(table, axis, x) for x in q]
    control = np.repeat(control, sub, axis=1)
    state, _ = rollout.rollout(model, data, initial, control)
    return state[:, sub - 1 :: sub, :][:, :, 1 + plant.qpos_index]


def write_figures(replays: list[Replay], out: Path) -> list[str]:
    """fit_<i>.png per log: measured and simulated positions and the residual; the file names."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = []
    for i, r in enumerate(replays):
        fig, axes = plt.subplots(2, 2, figsize=(12, 6), sharex=True)
        for a, axis in enumerate(AXES):
            axes[0, a].plot(r.t_s, r.measured_m[:, a] * 1e3, lw=1.0, label="measured")
            axes[0, a].plot(r.t_s, r.simulated_m[:, a] * 1e3, lw=0.8, ls="--", label="identified model")
            axes[0, a].set_ylabel(f"{axis} (mm)")
            axes[0, a].legend(loc="upper right")
            axes[1, a].plot(r.t_s, r.residual_m[:, a] * 1e6, lw=0.6)
            axes[1, a].set_ylabel(f"{axis} residual (um)")
            axes[1, a].set_xlabel("t (s)")
        fig.suptitle(f"{Path(r.path).name}: replay in {r.window_s:g} s windows from the measured state")
        fig.tight_layout()
        name = f"fit_{i}.png"
        fig.savefig(out / name, dpi=90)
        plt.close(fig)
        names.append(name)
    return names
