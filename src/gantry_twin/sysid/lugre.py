"""``identify --friction lugre``: the LuGre parameters of each axis from logs (:mod:`gantry_twin.plant.friction`).

Three stages, each on what the previous one found:

1. M, B, Af, dN by the linear regression of :func:`gantry_twin.sysid.identify.identify`;
2. Fc, Fs, vs, sigma2 from the friction force of the filtered regression, binned by velocity and fitted to
   :func:`gantry_twin.plant.friction.steady_force_n`; below ``fast_speed_m_s`` only steady samples count
   (:func:`steady_samples`: the plateaus of ``gantry-twin excite --plateaus``);
3. sigma0, sigma1 from windows around the velocity reversals replayed open loop through the plant of stages
   1-2 (:func:`gantry_twin.sysid.replay.replay_windows`), each window's offset + slope removed (:func:`detrend`).

(docs/logs.md, "--friction lugre")
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from gantry_twin.plant.friction import (
    PRESLIDING_M,
    STRIBECK_RATIO,
    VS_RANGE_M_S,
    Friction,
    LuGreAxis,
    LuGreParameters,
    steady_force_n,
)
from gantry_twin.plant.model import AXES, Plant, moving_masses_kg
from gantry_twin.settings import Count, Frequency, Range, validated
from gantry_twin.sysid.identify import Identified, axis_regressions, plant_xml
from gantry_twin.sysid.logs import Log, centred_velocity
from gantry_twin.sysid.replay import VELOCITY_FIT_S, replay_windows

#: The least number of steady velocity bins per direction below LuGreSettings.fast_speed_m_s (stage 2 fits four
#: parameters to the curve; docs/logs.md).
MIN_STEADY_BINS = 4
#: The LuGre parameters identified per axis, in identified.json's order, and their units.
LUGRE_NAMES = ("fc_n", "fs_n", "vs_m_s", "sigma2_ns_m", "sigma0_n_m", "sigma1_ns_m")


@validated("lugre")
class LuGreSettings:
    """How the LuGre stages select and fit (module docstring).

    sliding_speed_m_s, stick_memory_s: stage 2's samples (as :class:`IdentifySettings`'), filter_hz: its Hf.
    steady_s, steady_segment_s, steady_rel, steady_abs_m_s: a sample is steady when the speeds over every
    ``steady_segment_s`` stretch of the ``steady_s`` before it agree within steady_rel |v| + steady_abs_m_s
    (:func:`steady_samples`); fast_speed_m_s: above it every sample counts as steady.
    bins_per_decade: velocity bins; min_bin_samples: a bin's least count.
    reversal_before_s, reversal_after_s: stage 3's window around each reversal, s.
    reversal_speed_m_s: a reversal counts when the axis moved faster than this on both sides of it.
    max_windows: at most this many windows per log (evenly chosen).
    """

    sliding_speed_m_s: Range(0.0, 1.0, "m/s", lo_open=True) = 0.3e-3
    stick_memory_s: Range(0.0, 10.0, "s") = 0.03
    filter_hz: Frequency = 50.0
    steady_s: Range(0.0, 10.0, "s", lo_open=True) = 0.2
    steady_segment_s: Range(0.0, 10.0, "s", lo_open=True) = 0.05
    steady_rel: Range(0.0, 1.0) = 0.05
    steady_abs_m_s: Range(0.0, 1.0, "m/s") = 2.0e-5
    fast_speed_m_s: Range(0.0, 10.0, "m/s", lo_open=True) = 0.1
    bins_per_decade: Count(1, 100) = 8
    min_bin_samples: Count(1, 10**6) = 20
    reversal_before_s: Range(0.0, 10.0, "s") = 0.01
    reversal_after_s: Range(0.0, 10.0, "s", lo_open=True) = 0.03
    reversal_speed_m_s: Range(0.0, 10.0, "m/s", lo_open=True) = 0.02
    max_windows: Count(1, 10**5) = 200


@dataclass(frozen=True)
class LuGreFit:
    """Per axis (X, Y): the LuGre parameters, SI, and ci95 per name ([lo, hi] or None with ``ci_note``)."""

    axes: tuple[LuGreParameters, LuGreParameters]
    ci95: tuple[dict[str, list[float] | None], dict[str, list[float] | None]]
    ci_note: str
    bins: tuple[int, int]
    windows: int

    def friction(self) -> Friction:
        """The scenario's friction section of these parameters."""
        return Friction(model="lugre", **{a: LuGreAxis(**p._asdict()) for a, p in zip(AXES, self.axes, strict=True)})

    def parameters(self) -> dict[str, dict[str, dict[str, object]]]:
        """identified.json's ``lugre``: {axis: {name: {value, ci95, unit}}}."""
        units = {"fc_n": "N", "fs_n": "N", "vs_m_s": "m/s", "sigma2_ns_m": "N s/m", "sigma0_n_m": "N/m"}
        units["sigma1_ns_m"] = "N s/m"
        return {
            axis: {n: {"value": float(getattr(p, n)), "ci95": ci[n], "unit": units[n]} for n in LUGRE_NAMES}
            for axis, p, ci in zip(AXES, self.axes, self.ci95, strict=True)
        }


def steady_samples(log: Log, settings: LuGreSettings) -> np.ndarray:
    """(N, 2): True where the axis has slid (faster than ``sliding_speed_m_s``) at one speed for ``steady_s``: the
    speed over each ``steady_segment_s`` stretch ending every half segment within it agrees with the latest within
    steady_rel |v| + steady_abs_m_s."""
    ts = log.sample_period_s
    m = max(1, int(round(settings.steady_segment_s / ts)))
    half = max(1, m // 2)
    shifts = range(0, int(round(settings.steady_s / ts)) - m + 1, half)
    q = log.q_m
    v = np.full(q.shape, np.nan)
    v[m:] = (q[m:] - q[:-m]) / (m * ts)  # over the segment ending at each sample
    tolerance = settings.steady_rel * np.abs(v) + settings.steady_abs_m_s
    steady = np.abs(v) >= settings.sliding_speed_m_s  # NaN (before the log's start) compares False
    for shift in shifts[1:]:
        earlier = np.full(q.shape, np.nan)
        earlier[shift:] = v[:-shift]
        steady &= np.abs(earlier - v) <= tolerance
    return steady


def binned_friction(logs: Sequence[Log], base: Identified, settings: LuGreSettings) -> list[tuple[np.ndarray, ...]]:
    """Per axis: (v m/s, F volts, count) per velocity bin (stage 2 of the module docstring)."""
    stage = replace(
        base.settings,
        filter_hz=(settings.filter_hz, settings.filter_hz),
        sliding_speed_m_s=settings.sliding_speed_m_s,
        stick_memory_s=settings.stick_memory_s,
    )
    steady = [steady_samples(log, settings) for log in logs]
    out = []
    for axis, reg in enumerate(axis_regressions(logs, stage)):
        m, dn = base.theta[axis], base.theta[6 + axis]
        use = np.abs(reg.x[:, 1]) >= settings.fast_speed_m_s
        for index, flags in enumerate(steady):
            mine = reg.log_index == index
            use[mine] |= flags[reg.sample[mine], axis]
        force = (reg.y - m * reg.x[:, 0] - dn * reg.x[:, 3])[use]  # B x_f' + friction, filtered, volts
        v = reg.x[use, 1]
        lo, hi = settings.sliding_speed_m_s, max(np.abs(v).max(initial=0.0), 2 * settings.sliding_speed_m_s)
        edges = np.geomspace(lo, hi, max(2, int(math.ceil(np.log10(hi / lo) * settings.bins_per_decade)) + 1))
        rows = []
        for sign in (-1.0, 1.0):
            speed = sign * v
            which = np.digitize(speed, edges) - 1
            for b in range(edges.size - 1):
                sel = which == b
                if sel.sum() >= settings.min_bin_samples:
                    rows.append((float(v[sel].mean()), float(force[sel].mean()), int(sel.sum())))
        table = np.array(rows, dtype=float).reshape(-1, 3)  # no rows: empty columns (the caller says why)
        out.append((table[:, 0], table[:, 1], table[:, 2].astype(int)))
    return out


def fit_steady(v: np.ndarray, force_n: np.ndarray, guess: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(Fc, Fs, vs, sigma2) and their ci95 (4, 2) fitting sign(v) g(v) + sigma2 v to the bins (SI).

    guess: (Af kf, B kf) of stage 1. Fs / Fc within friction.STRIBECK_RATIO, vs within LuGreAxis's range.
    """
    from scipy.optimize import least_squares

    vs_range = VS_RANGE_M_S

    def unpack(z: np.ndarray) -> LuGreParameters:
        fc, ratio, log_vs, sigma2 = z
        return LuGreParameters(0.0, 0.0, fc, fc * ratio, 10.0**log_vs, sigma2)

    def residual(z: np.ndarray) -> np.ndarray:
        return steady_force_n(unpack(z), v) - force_n

    af, b = guess
    lo = [0.0, STRIBECK_RATIO[0], math.log10(vs_range[0]), 0.0]
    hi = [10.0 * af, STRIBECK_RATIO[1], math.log10(vs_range[1]), 10.0 * b]
    best = None
    for log_vs in np.linspace(lo[2] + 0.5, hi[2] - 0.2, 5):  # the Stribeck velocity has local minima
        r = least_squares(residual, [af, 1.2, log_vs, b], bounds=(lo, hi), x_scale=[af, 0.2, 0.5, b])
        if best is None or r.cost < best.cost:
            best = r
    p = unpack(best.x)
    values = np.array([p.fc_n, p.fs_n, p.vs_m_s, p.sigma2_ns_m])
    dof = max(1, v.size - 4)
    try:
        bread = np.linalg.inv(best.jac.T @ best.jac)
        meat = (best.jac * best.fun[:, None]).T @ (best.jac * best.fun[:, None])  # each bin its own variance
        cov = bread @ meat @ bread * (v.size / dof)
    except np.linalg.LinAlgError:
        return values, np.full((4, 2), np.nan)
    half = 1.959963984540054 * np.sqrt(np.clip(np.diag(cov), 0.0, None))
    z_lo, z_hi = best.x - half, best.x + half
    lo_p, hi_p = unpack(z_lo), unpack(z_hi)
    ci = np.array(
        [
            [p.fc_n - half[0], p.fc_n + half[0]],
            [min(lo_p.fs_n, hi_p.fs_n), max(lo_p.fs_n, hi_p.fs_n)],  # Fs = Fc ratio: the ratio's interval
            [lo_p.vs_m_s, hi_p.vs_m_s],
            [p.sigma2_ns_m - half[3], p.sigma2_ns_m + half[3]],
        ]
    )
    return values, ci


def reversal_starts(log: Log, settings: LuGreSettings) -> tuple[np.ndarray, int]:
    """Stage 3's windows: (start samples, length) around each reversal of either axis (module docstring)."""
    ts = log.sample_period_s
    v = centred_velocity(log.q_m, 5, ts)
    before, after = int(round(settings.reversal_before_s / ts)), int(round(settings.reversal_after_s / ts))
    half = max(1, int(round(0.5 * VELOCITY_FIT_S / ts)))
    starts = []
    for axis in range(2):
        fast = np.abs(v[:, axis]) > settings.reversal_speed_m_s
        sign = np.sign(v[:, axis]) * fast
        idx = np.flatnonzero(fast)
        for a, b in zip(idx[:-1], idx[1:], strict=True):
            if sign[a] != sign[b] and b - a < before + after:  # a reversal between two fast samples
                starts.append(a - before // 2)
    starts = np.array(sorted(s for s in starts if half < s < log.samples - after - before - half - 1), dtype=int)
    if starts.size > settings.max_windows:
        starts = starts[np.linspace(0, starts.size - 1, settings.max_windows).round().astype(int)]
    return starts, before + after


def detrend(length: int) -> np.ndarray:
    """(length, length): the projection that removes a window's best-fit offset + slope in time.

    Applied to the replay residual it leaves out what the window's initial state (the encoder's position and
    the velocity estimated from it) gets wrong to first order, and keeps the curved pre-sliding response.
    """
    basis = np.stack([np.ones(length), np.arange(length, dtype=float)], axis=1)
    return np.eye(length) - basis @ np.linalg.pinv(basis)


def fit_bristle(plant: Plant, logs: Sequence[Log], settings: LuGreSettings) -> tuple[np.ndarray, np.ndarray, int]:
    """(sigma0 (2,), sigma1 (2,), windows): stage 3 of the module docstring on ``plant`` (its friction edited)."""
    from scipy.optimize import least_squares

    model = plant.model
    act = plant.friction_index
    mass = moving_masses_kg(model, plant.dof_index)
    windows = [(log, *reversal_starts(log, settings)) for log in logs]
    count = sum(w[1].size for w in windows)
    if count == 0:
        raise ValueError("no velocity reversals faster than the LuGre settings' reversal speed: cannot see sigma0")
    fc = model.actuator_biasprm[act, 3]
    lo_log = np.log10(fc / PRESLIDING_M[1])
    hi_log = np.log10(fc / PRESLIDING_M[0])

    def apply(z: np.ndarray) -> None:
        sigma0 = 10.0 ** z[:2]
        model.actuator_dynprm[act, 5] = sigma0
        model.actuator_dynprm[act, 6] = z[2:] * 2.0 * np.sqrt(sigma0 * mass)

    def residual(z: np.ndarray) -> np.ndarray:
        apply(z)
        parts = []
        for log, starts, length in windows:
            if starts.size:
                sim = replay_windows(plant, log, starts, length)
                idx = starts[:, None] + 1 + np.arange(length)[None, :]
                parts.append(np.einsum("ij,wjk->wik", detrend(length), log.q_m[idx] - sim).reshape(-1) * 1e6)
        return np.concatenate(parts)

    z0 = np.concatenate([0.5 * (lo_log + hi_log), [0.05, 0.05]])
    r = least_squares(
        residual,
        z0,
        bounds=(np.concatenate([lo_log, [0.0, 0.0]]), np.concatenate([hi_log, [1.0, 1.0]])),
        diff_step=[1e-3, 1e-3, 1e-2, 1e-2],
    )
    apply(r.x)
    return 10.0 ** r.x[:2], model.actuator_dynprm[act, 6].copy(), count


def identify_lugre(logs: Sequence[Log], base: Identified, settings: LuGreSettings | None = None) -> LuGreFit:
    """The LuGre parameters of both axes (module docstring); ``base``: stage 1's result on the same logs."""
    settings = settings or LuGreSettings()
    steady, cis, nbins = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "plant.xml"
        path.write_text(plant_xml(base.theta))
        gear = Plant(model_path=path).gear_n_per_v
        for axis, (v, force_v, _) in enumerate(binned_friction(logs, base, settings)):
            slow = [int(np.sum((sign * v > 0) & (np.abs(v) < settings.fast_speed_m_s))) for sign in (-1, 1)]
            if v.size < 6 or min(slow) < MIN_STEADY_BINS:
                raise ValueError(
                    f"{AXES[axis]} axis: {v.size} velocity bins, {min(slow)} of them steady below "
                    f"{settings.fast_speed_m_s:g} m/s in one direction (at least {MIN_STEADY_BINS}): the logs "
                    "must hold constant-velocity stretches at low speeds both ways (gantry-twin excite --plateaus)"
                )
            guess = (base.theta[4 + axis] * gear[axis], base.theta[2 + axis] * gear[axis])
            values, ci = fit_steady(v, force_v * gear[axis], guess)
            steady.append(values)
            cis.append(ci)
            nbins.append(v.size)
        start = {
            a: LuGreAxis(fc_n=s[0], fs_n=s[1], vs_m_s=s[2], sigma2_ns_m=s[3], sigma0_n_m=s[0] / 5.0e-6, sigma1_ns_m=0.0)
            for a, s in zip(AXES, steady, strict=True)
        }
        plant = Plant(model_path=path, friction=Friction(model="lugre", **start))
        sigma0, sigma1, count = fit_bristle(plant, logs, settings)
    axes = tuple(LuGreParameters(float(sigma0[i]), float(sigma1[i]), *(float(x) for x in steady[i])) for i in range(2))
    note = "sigma0, sigma1: the replay residuals are correlated within a window; the measured spread: docs/logs.md"
    ci95 = tuple(
        {
            **{n: [float(cis[i][j, 0]), float(cis[i][j, 1])] for j, n in enumerate(LUGRE_NAMES[:4])},
            "sigma0_n_m": None,
            "sigma1_ns_m": None,
        }
        for i in range(2)
    )
    return LuGreFit(axes, ci95, note, (nbins[0], nbins[1]), count)
