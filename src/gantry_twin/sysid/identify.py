"""Identify the plant from logs: M, B, Af, dN per axis by least squares on filtered signals.

The model ``M q'' + B q' + Af sign(q') + dN = u`` (volts, while the axis slides) passes on both sides
through the estimator's filter Hf, discretised as DIARC's estimator does it
(:func:`gantry_twin.numerics.estimation.filter_axis`), which gives eq. (25)'s regression
``u_f = [x_f'', x_f', Sf_f, -1_f] [M, B, Af, dN]^T``, one row per sample. Offline, Sf is that of a centred
velocity with a steep slope, and the samples whose filter memory (``stick_memory_s``) holds one slower than
``sliding_speed_m_s`` are left out (the axis may stick). 95 % intervals: Newey-West (:func:`hac_covariance`).
The LuGre parameters build on this fit: :mod:`gantry_twin.sysid.lugre`; the command: :mod:`gantry_twin.cli.identify`.

(docs/logs.md, "gantry-twin identify")
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gantry_twin.numerics.estimation import (
    FilterHz,
    FilterZeta,
    FrictionSlope,
    discretise_filter,
    filter_axis,
    filter_steady_state,
    friction_shape,
)
from gantry_twin.plant.model import AXES, THETA_NAMES, THETA_UNITS, build_spec, moving_masses_kg
from gantry_twin.settings import Count, Range, validated
from gantry_twin.sysid.logs import Log, centred_velocity

#: Columns of one axis' regression, in THETA_NAMES' per-axis order.
COLUMNS = ("M", "B", "Af", "dN")
#: The two-sided 95 % quantile of the normal distribution.
Z95 = 1.959963984540054


@validated("identify")
class IdentifySettings:
    """How :func:`identify` filters and selects the samples (module docstring).

    filter_hz: Hf per axis, Hz (identification's own 50 Hz, well above the
    excitation's motion, keeps the encoder's quantisation out of x_f''; the
    on-line recommended estimator uses 10 Hz); filter_zeta: its damping.
    friction_slope_s_m: slope of Sf(v) = (2/pi) atan(slope v), s/m.
    velocity_half_width: samples each side of the centred velocity.
    sliding_speed_m_s, stick_memory_s: the samples left out (module docstring).
    hac_lag_s: the lag over which the residuals are taken as correlated, s.
    """

    filter_hz: FilterHz = (50.0, 50.0)
    filter_zeta: FilterZeta = 0.7
    friction_slope_s_m: FrictionSlope = 1.0e6
    velocity_half_width: Count(1, 500) = 5
    sliding_speed_m_s: Range(0.0, 1.0, "m/s", lo_open=True) = 2.0e-3
    stick_memory_s: Range(0.0, 10.0, "s") = 0.03
    hac_lag_s: Range(0.0, 60.0, "s") = 0.05


@dataclass(frozen=True)
class AxisRegression:
    """One axis' filtered regression over the samples kept: rows X (n, 4), target y (n,), the log's index and
    each row's sample in its log."""

    x: np.ndarray
    y: np.ndarray
    log_index: np.ndarray
    sample: np.ndarray


@dataclass(frozen=True)
class Identified:
    """The result: theta (8,) in THETA_NAMES' order, volt units; ci95 (8, 2); samples used per axis; settings."""

    theta: np.ndarray
    ci95: np.ndarray
    samples_used: tuple[int, int]
    residual_rms_v: tuple[float, float]
    settings: IdentifySettings

    def parameters(self) -> dict[str, dict[str, object]]:
        """identified.json's ``parameters``: {name: {value, ci95: [lo, hi], unit}}."""
        return {
            name: {"value": float(self.theta[j]), "ci95": [float(x) for x in self.ci95[j]], "unit": THETA_UNITS[j]}
            for j, name in enumerate(THETA_NAMES)
        }


def axis_regressions(logs: Sequence[Log], settings: IdentifySettings) -> list[AxisRegression]:
    """The filtered regression of each axis over all logs, the samples left out removed (module docstring)."""
    rows: list[list[tuple[np.ndarray, ...]]] = [[], []]
    for index, log in enumerate(logs):
        ts = log.sample_period_s
        v = centred_velocity(log.q_m, settings.velocity_half_width, ts)  # (N, 2); v[k]: interval k-1 -> k
        memory = max(1, int(round(settings.stick_memory_s / ts)))
        for axis in range(2):
            disc = discretise_filter(2.0 * np.pi * settings.filter_hz[axis], settings.filter_zeta, ts)
            q, u = log.q_m[:, axis], log.u_v[:, axis]
            sf = friction_shape(v[:, axis], settings.friction_slope_s_m)
            z = filter_steady_state(disc, q[0], v[0, axis], (sf[0], 1.0, u[0]))
            held = np.stack([sf[1:], np.ones(q.size - 1), u[:-1]], axis=1)  # over interval k-1 -> k: u[k-1]
            acc, vel, filtered = filter_axis(z, disc, q[1:], q[:-1], held, ts)
            x = np.stack([acc, vel, filtered[:, 0], -filtered[:, 1]], axis=1)
            slow = (np.abs(v[1:, axis]) < settings.sliding_speed_m_s).astype(float)
            recent = np.convolve(slow, np.ones(memory + 1))[: slow.size] > 0.0  # a slow sample within memory
            keep = ~recent
            keep[: 4 * memory] = False  # the filters' start
            kept = np.flatnonzero(keep)
            rows[axis].append((x[keep], filtered[keep, 2], np.full(kept.size, index), kept + 1))
    return [AxisRegression(*(np.concatenate([r[i] for r in rows[a]]) for i in range(4))) for a in range(2)]


def hac_covariance(x: np.ndarray, residual: np.ndarray, groups: np.ndarray, lag: int) -> np.ndarray:
    """Newey-West covariance of the least-squares solution (Bartlett weights up to ``lag``), per group summed."""
    bread = np.linalg.inv(x.T @ x)
    meat = np.zeros((x.shape[1], x.shape[1]))
    for g in np.unique(groups):
        h = x[groups == g] * residual[groups == g][:, None]
        meat += h.T @ h
        for j in range(1, min(lag, h.shape[0] - 1) + 1):
            c = h[j:].T @ h[:-j]
            meat += (1.0 - j / (lag + 1.0)) * (c + c.T)
    return bread @ meat @ bread


def identify(logs: Sequence[Log], settings: IdentifySettings | None = None) -> Identified:
    """M, B, Af, dN of both axes from the logs (module docstring)."""
    settings = settings or IdentifySettings()
    theta, ci = np.zeros(8), np.zeros((8, 2))
    used, rms = [], []
    ts = min(log.sample_period_s for log in logs)
    for axis, reg in enumerate(axis_regressions(logs, settings)):
        if reg.y.size < 10 * len(COLUMNS):
            raise ValueError(
                f"{AXES[axis]} axis: only {reg.y.size} samples while sliding; the logs must move the axis "
                f"faster than {settings.sliding_speed_m_s * 1e3:g} mm/s both ways"
            )
        scale = np.sqrt((reg.x**2).mean(axis=0))  # columns of unit rms: a well-conditioned solve
        solution, *_ = np.linalg.lstsq(reg.x / scale, reg.y, rcond=None)
        beta = solution / scale
        residual = reg.y - reg.x @ beta
        cov = hac_covariance(reg.x, residual, reg.log_index, max(1, int(round(settings.hac_lag_s / ts))))
        half = Z95 * np.sqrt(np.clip(np.diag(cov), 0.0, None))
        for c in range(len(COLUMNS)):
            j = 2 * c + axis
            theta[j] = beta[c]
            ci[j] = (beta[c] - half[c], beta[c] + half[c])
        used.append(int(reg.y.size))
        rms.append(float(np.sqrt(np.mean(residual**2))))
    return Identified(theta, ci, (used[0], used[1]), (rms[0], rms[1]), settings)


# -- the plant file -------------------------------------------------------------------------------


class UnphysicalFit(ValueError):
    """The logs cannot identify this machine's model: the regression's theta is no machine of this kind (a mass
    <= 0, a negative damping or friction, or masses no positive carriage masses give). Nothing is written."""


#: What a log needs to identify this machine's model: the end of every UnphysicalFit's message.
LOG_NEEDS = (
    "it needs a log of a gantry like this one (Y carrying X) whose volts push each axis the way their sign says "
    "(u_x_v > 0 accelerates +x), both axes moved both ways (docs/logs.md)"
)


def check_physical(theta: np.ndarray) -> None:
    """UnphysicalFit naming each entry that no machine has: M1, M2 > 0; B1, B2, Af1, Af2 >= 0 (dN may be any)."""
    names = ("M1", "M2", "B1", "B2", "Af1", "Af2")
    bad = [
        f"{n} = {theta[j]:.4g} {THETA_UNITS[j]}"
        for j, n in enumerate(names)
        if not (theta[j] > 0.0 if j < 2 else theta[j] >= 0.0)
    ]
    if bad:
        raise UnphysicalFit(
            f"cannot identify this machine's model: the fit gives {', '.join(bad)} (a mass must be > 0, a damping "
            f"or friction >= 0); {LOG_NEEDS}"
        )


def plant_xml(theta: np.ndarray, note: str = "", model_path: Path | None = None) -> str:
    """The MJCF of the gantry with identified M, B, Af (volt units), as text.

    The moving masses are met by changing the carriages' masses (X: M1 gear;
    Y, which carries X: M2 gear in all), damping = B gear, frictionloss =
    Af gear. dN has no place in the model (the twin has no constant force):
    it is reported, not written. UnphysicalFit (a ValueError) for a theta no
    machine has, and if the masses cannot be met (M2 <= M1: the Y axis moves the X carriage too).
    """
    check_physical(theta)
    spec = build_spec(None, model_path)
    model = spec.compile()
    dofs = np.array([model.joint(a).dofadr[0] for a in AXES])
    gear = model.actuator_gear[[model.actuator(f"{a}_motor").id for a in AXES], 0]
    target_kg = theta[0:2] * gear
    now_kg = moving_masses_kg(model, dofs)
    dx = target_kg[0] - now_kg[0]
    dy = target_kg[1] - now_kg[1] - dx
    x_body, y_body = spec.body("x_carriage"), spec.body("y_carriage")
    if x_body.mass + dx <= 0.0 or y_body.mass + dy <= 0.0:
        raise UnphysicalFit(
            f"cannot identify this machine's model: the fit gives M1 = {theta[0]:.4g}, M2 = {theta[1]:.4g} V/(m/s^2), "
            f"which no positive carriage masses give (Y moves the X carriage too: M2 must exceed M1); {LOG_NEEDS}"
        )
    x_body.mass += dx
    y_body.mass += dy
    for i, axis in enumerate(AXES):
        joint = spec.joint(axis)
        damping = np.array(joint.damping, dtype=float)  # MuJoCo keeps room for more terms: the first is viscous
        damping[0] = theta[2 + i] * gear[i]
        joint.damping = damping
        joint.frictionloss = float(theta[4 + i] * gear[i])
    comment = (note or "identified plant").replace("--", "- -")
    return f"<!-- {comment} -->\n{spec.to_xml()}"
