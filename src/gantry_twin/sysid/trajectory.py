"""An identification trajectory, and running it on the twin: ``gantry-twin excite``.

:class:`Multisine`: per axis a multisine, faded in and out, starting and ending at rest at the centre of
travel, the two axes on interleaved frequencies, scaled (:func:`design`) to the tightest of the position,
speed and nominal-command limits below. :func:`with_plateaus` appends the constant-velocity
:class:`Plateaus` of ``--plateaus`` (for the LuGre fit). The twin runs it in closed loop under the PD
controller (:func:`run_on_twin`), as a machine's own controller would; the log has the encoder
positions, the commands and the desired positions.

(docs/logs.md, "gantry-twin excite")
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gantry_twin.paths.contours import TimingLaw
from gantry_twin.plant.model import Payload, Plant

#: Position limit of the trajectory, m: the 255 mm half travel less a margin for the tracking error.
POSITION_LIMIT_M = 0.2
#: Speed limit, m/s.
SPEED_LIMIT_M_S = 0.5
#: Nominal command budget, V: M a + B v + Af of the heaviest machine the trajectory is sized for
#: (:func:`budget_theta`), leaving the rest of the +-10 V DAC range to the feedback.
COMMAND_BUDGET_V = 6.0
#: The frequencies of the multisine, Hz, as multiples of 1 / duration: X takes the odd entries, Y the even.
FREQUENCY_RANGE_HZ = (0.2, 5.0)
FREQUENCIES_PER_AXIS = 8
#: Longest trajectory, s: six times the default 20 s; its tables and the twin's run stay in bounded memory
#: (the trajectory's samples are held at once: 1e5 s once asked for 12 GiB).
DURATION_MAX_S = 120.0
#: The payload, kg, of the heaviest machine the command budget is computed for.
BUDGET_PAYLOAD_KG = 10.0
#: The LuGre section (:class:`Plateaus`): its lowest and highest speed, m/s, the number of speeds (log-spaced),
#: how long each is held, s (the identifier's settling window and the averaging after it: identify_lugre), and
#: the smoothstep between two speeds, s.
PLATEAU_SPEEDS_M_S = (1.0e-3, 0.1)
PLATEAU_COUNT = 9
PLATEAU_HOLD_S = 0.4
PLATEAU_RAMP_S = 0.1


@dataclass(frozen=True)
class Multisine:
    """A path p(phi) with phi the time in seconds (``TimingLaw(1.0)``): the trajectory of the module docstring.

    frequencies_hz, amplitudes_m, phases_rad: (2, K) per axis; duration_s, fade_s: the fade window.
    """

    frequencies_hz: np.ndarray
    amplitudes_m: np.ndarray
    phases_rad: np.ndarray
    duration_s: float
    fade_s: float

    @property
    def period_rad(self) -> float:
        return self.duration_s

    def derivatives(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """p, p', p'', p''' (..., 2) at times phi (s): the sines times the fade window (Leibniz' rule)."""
        t = np.asarray(phi, dtype=float)
        s = _sines(self, t)
        w = _window(t, self.duration_s, self.fade_s)
        p = w[0][..., None] * s[0]
        dp = w[1][..., None] * s[0] + w[0][..., None] * s[1]
        ddp = w[2][..., None] * s[0] + 2 * w[1][..., None] * s[1] + w[0][..., None] * s[2]
        dddp = w[3][..., None] * s[0] + 3 * w[2][..., None] * s[1] + 3 * w[1][..., None] * s[2] + w[0][..., None] * s[3]
        return p, dp, ddp, dddp


def _sines(m: Multisine, t: np.ndarray) -> list[np.ndarray]:
    """The sum of sines per axis and its first three time derivatives, each (..., 2)."""
    omega = 2.0 * np.pi * m.frequencies_hz  # (2, K)
    arg = t[..., None, None] * omega + m.phases_rad  # (..., 2, K)
    sin, cos = np.sin(arg), np.cos(arg)
    a = m.amplitudes_m
    return [
        (a * sin).sum(-1),
        (a * omega * cos).sum(-1),
        (-a * omega**2 * sin).sum(-1),
        (-a * omega**3 * cos).sum(-1),
    ]


def _window(t: np.ndarray, duration_s: float, fade_s: float) -> list[np.ndarray]:
    """w, w', w'', w''': a quintic smoothstep up over [0, fade] and down over [duration - fade, duration]."""
    up = _smoothstep(t / fade_s, fade_s)
    down = _smoothstep((duration_s - t) / fade_s, fade_s)
    # w = up * down (they never overlap when duration >= 2 fade); down's derivatives change sign with t.
    d = [down[0], -down[1], down[2], -down[3]]
    return [
        up[0] * d[0],
        up[1] * d[0] + up[0] * d[1],
        up[2] * d[0] + 2 * up[1] * d[1] + up[0] * d[2],
        up[3] * d[0] + 3 * up[2] * d[1] + 3 * up[1] * d[2] + up[0] * d[3],
    ]


def _smoothstep(tau: np.ndarray, scale_s: float) -> list[np.ndarray]:
    """10 tau^3 - 15 tau^4 + 6 tau^5 on [0, 1] (0 before, 1 after) and its time derivatives (tau = t / scale)."""
    x = np.clip(tau, 0.0, 1.0)
    inside = (tau > 0.0) & (tau < 1.0)
    return [
        10 * x**3 - 15 * x**4 + 6 * x**5,
        np.where(inside, (30 * x**2 - 60 * x**3 + 30 * x**4) / scale_s, 0.0),
        np.where(inside, (60 * x - 180 * x**2 + 120 * x**3) / scale_s**2, 0.0),
        np.where(inside, (60 - 360 * x + 360 * x**2) / scale_s**3, 0.0),
    ]


@dataclass(frozen=True)
class Plateaus:
    """Constant-velocity plateaus, both axes alike, from ``start_s``: from rest up through ``speeds_m_s`` one way
    (each held ``hold_s``), back through rest and the same speeds the other way, ending at rest where it started.

    The steady friction-velocity curve (Stribeck) is measured where the bristle and the filters have settled:
    a path p(phi), phi the time in s, like :class:`Multisine` (zero before ``start_s``). Between two speeds the
    velocity follows a quintic smoothstep over ``ramp_s``.
    """

    speeds_m_s: np.ndarray
    hold_s: float
    ramp_s: float
    start_s: float = 0.0

    @property
    def levels_m_s(self) -> np.ndarray:
        """The velocities held in turn: 0, s_1 .. s_n, 0, -s_1 .. -s_n, 0."""
        up = np.asarray(self.speeds_m_s, dtype=float)
        return np.concatenate([[0.0], up, [0.0], -up, [0.0]])

    @property
    def ramp_starts_s(self) -> np.ndarray:
        """When each smoothstep between two consecutive levels starts, s (the middle rest is not held)."""
        holds = np.where(self.levels_m_s[1:-1] != 0.0, self.hold_s, 0.0)
        return self.start_s + np.concatenate([[0.0], np.cumsum(self.ramp_s + holds)])

    @property
    def duration_s(self) -> float:
        return float(self.ramp_starts_s[-1] + self.ramp_s)

    @property
    def period_rad(self) -> float:
        return self.duration_s

    def derivatives(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """p, p', p'', p''' (..., 2) at times phi (s): v = sum_j dv_j S((t - t_j) / ramp), p its integral."""
        t = np.asarray(phi, dtype=float)[..., None]
        dv = np.diff(self.levels_m_s)
        tau = (t - self.ramp_starts_s) / self.ramp_s
        step = _smoothstep(tau, self.ramp_s)
        x = np.clip(tau, 0.0, 1.0)
        integral = np.where(tau >= 1.0, tau - 0.5, 2.5 * x**4 - 3.0 * x**5 + x**6)  # int_0^tau S
        out = [(dv * self.ramp_s * integral).sum(-1)] + [(dv * d).sum(-1) for d in step[:3]]
        return tuple(np.repeat(o[..., None], 2, axis=-1) for o in out)


@dataclass(frozen=True)
class Sequenced:
    """Paths, each zero outside its own time span, one after the other: p = the sum of theirs."""

    parts: tuple

    @property
    def duration_s(self) -> float:
        return max(part.period_rad for part in self.parts)

    @property
    def period_rad(self) -> float:
        return self.duration_s

    def derivatives(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return tuple(sum(d) for d in zip(*(part.derivatives(phi) for part in self.parts), strict=True))


def with_plateaus(path: Multisine) -> Sequenced:
    """The LuGre excitation: ``path``, then the :class:`Plateaus` of PLATEAU_SPEEDS_M_S (docs/logs.md)."""
    speeds = np.geomspace(*PLATEAU_SPEEDS_M_S, PLATEAU_COUNT)
    return Sequenced((path, Plateaus(speeds, PLATEAU_HOLD_S, PLATEAU_RAMP_S, start_s=path.duration_s)))


def budget_theta() -> np.ndarray:
    """The heaviest machine the trajectory is sized for: the twin's with a BUDGET_PAYLOAD_KG payload and
    B, Af +30 % (volt units, theta order)."""
    theta = Plant(Payload(mass_kg=BUDGET_PAYLOAD_KG)).true_parameters()
    theta[2:6] *= 1.3
    return theta


def design(duration_s: float = 20.0, fade_s: float = 1.0, theta: np.ndarray | None = None) -> Multisine:
    """The multisine of the module docstring for a run of ``duration_s``, scaled to the limits."""
    if not (math.isfinite(fade_s) and fade_s > 0.0):
        raise ValueError(f"fade_s: must be a number > 0 s, got {fade_s:g}")
    if not (math.isfinite(duration_s) and 4.0 * fade_s <= duration_s <= DURATION_MAX_S):
        raise ValueError(
            f"duration_s: must be in [4 fade_s = {4 * fade_s:g}, {DURATION_MAX_S:g}] s, got {duration_s:g}"
        )
    theta = budget_theta() if theta is None else theta
    base = 1.0 / duration_s
    lo, hi = FREQUENCY_RANGE_HZ
    grid = np.unique(np.round(np.geomspace(lo, hi, 2 * FREQUENCIES_PER_AXIS) / base)) * base
    grid = grid[: 2 * (grid.size // 2)]
    freqs = np.stack([grid[0::2], grid[1::2]])
    k = np.arange(freqs.shape[1])
    phases = np.stack([-np.pi * k * (k + 1) / k.size, -np.pi * k * (k + 1) / k.size + np.pi / 3])  # Schroeder
    amps = 1.0 / (2.0 * np.pi * freqs)  # equal velocity amplitude per component
    shape = Multisine(freqs, amps, phases, duration_s, fade_s)
    t = np.arange(0.0, duration_s, 1e-3)
    p, dp, ddp, _ = shape.derivatives(t)
    volts = theta[0:2] * np.abs(ddp) + theta[2:4] * np.abs(dp) + theta[4:6]
    scale = np.minimum.reduce(
        [
            POSITION_LIMIT_M / np.abs(p).max(axis=0),
            SPEED_LIMIT_M_S / np.abs(dp).max(axis=0),
            (COMMAND_BUDGET_V - theta[4:6]) / (volts - theta[4:6]).max(axis=0),
        ]
    )
    return Multisine(freqs, amps * scale[:, None], phases, duration_s, fade_s)


def trajectory_table(path: Multisine | Sequenced, sample_period_s: float) -> dict[str, np.ndarray]:
    """The trajectory users run on their machine: t_s, x_d_m, y_d_m and its velocity and acceleration."""
    t = np.arange(int(round(path.duration_s / sample_period_s)) + 1) * sample_period_s
    p, dp, ddp, _ = path.derivatives(t)
    return {
        "t_s": t,
        "x_d_m": p[:, 0],
        "y_d_m": p[:, 1],
        "vx_d_m_s": dp[:, 0],
        "vy_d_m_s": dp[:, 1],
        "ax_d_m_s2": ddp[:, 0],
        "ay_d_m_s2": ddp[:, 1],
    }


def perturbed_plant(
    payload_kg: float = 0.0,
    viscous_scale: tuple[float, float] = (1.0, 1.0),
    coulomb_scale: tuple[float, float] = (1.0, 1.0),
    model_path: Path | None = None,
) -> Plant:
    """The twin with a payload and its joint damping (B) and frictionloss (Af) scaled per axis (X, Y)."""
    plant = Plant(Payload(mass_kg=payload_kg), model_path=model_path)
    dofs = plant.dof_index
    plant.model.dof_damping[dofs] *= np.asarray(viscous_scale, dtype=float)
    plant.model.dof_frictionloss[dofs] *= np.asarray(coulomb_scale, dtype=float)
    return plant


def random_plant(rng: np.random.Generator) -> Plant:
    """A twin drawn as the identification acceptance draws them (docs/logs.md): payload uniform in 0-10 kg,
    each axis' B and Af uniform within +-30 % of the model's."""
    payload = float(rng.uniform(0.0, 10.0))
    return perturbed_plant(payload, tuple(rng.uniform(0.7, 1.3, 2)), tuple(rng.uniform(0.7, 1.3, 2)))


#: The LuGre acceptance's plausible draws (within friction.LuGreAxis's ranges): Fs / Fc, vs (m/s, log-uniform), the
#: pre-sliding distance Fc / sigma0 (m, log-uniform) and sigma1 / sqrt(sigma0 * 1 kg).
LUGRE_DRAW = {
    "fs_over_fc": (1.1, 1.6),
    "vs_m_s": (2.0e-3, 20.0e-3),
    "presliding_m": (2.0e-6, 20.0e-6),
    "sigma1": (0.1, 1.0),
}


def random_lugre_plant(rng: np.random.Generator) -> Plant:
    """A LuGre twin drawn for the LuGre identification acceptance (docs/logs.md): payload 0-10 kg, each
    axis' sigma2 and Fc within +-30 % of the model's B kf and Af kf, and Fs / Fc, vs, the pre-sliding distance
    and sigma1 from :data:`LUGRE_DRAW`."""
    from gantry_twin.plant.friction import Friction, LuGreAxis

    payload = float(rng.uniform(0.0, 10.0))
    base = Plant()
    axes = {}
    for i, axis in enumerate(("x", "y")):
        fc = float(base.model.dof_frictionloss[base.dof_index[i]] * rng.uniform(0.7, 1.3))
        sigma2 = float(base.model.dof_damping[base.dof_index[i]] * rng.uniform(0.7, 1.3))
        fs = fc * float(rng.uniform(*LUGRE_DRAW["fs_over_fc"]))
        vs = float(np.exp(rng.uniform(*np.log(LUGRE_DRAW["vs_m_s"]))))
        sigma0 = fc / float(np.exp(rng.uniform(*np.log(LUGRE_DRAW["presliding_m"]))))
        sigma1 = float(rng.uniform(*LUGRE_DRAW["sigma1"]) * np.sqrt(sigma0))
        axes[axis] = LuGreAxis(sigma0_n_m=sigma0, sigma1_ns_m=sigma1, fc_n=fc, fs_n=fs, vs_m_s=vs, sigma2_ns_m=sigma2)
    return Plant(Payload(mass_kg=payload), friction=Friction(model="lugre", **axes))


def run_on_twin(path: Multisine | Sequenced, plant: Plant, sensing=None, prog: str | None = None):
    """Run the trajectory on the twin under PD control (module docstring); the trace.

    prog: a command's name, to announce on stderr (counting seconds on a terminal) a first compile of the loop
    (:func:`gantry_twin.loop.compiling.compile_notice`); None: nothing is printed.
    """
    from gantry_twin.controllers import create
    from gantry_twin.loop.compiling import compile_notice
    from gantry_twin.loop.simulate import simulate

    controller = create("pd")
    observers = () if prog is None else (compile_notice(controller, prog),)
    with np.errstate(invalid="ignore", divide="ignore"):  # the tangent angle at rest (both axes stopped) is 0/0
        return simulate(
            plant, path, TimingLaw(1.0), controller, duration_s=path.duration_s, sensing=sensing, observers=observers
        )


def log_of(trace) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A trace as a log's columns: t_s, u_v, encoder positions, desired positions."""
    n = trace.filled
    return trace.t_s[:n], trace.u_v[:n], trace.q_meas_m[:n], trace.q_d_m[:n]


# -- the command ---------------------------------------------------------------------------------
