"""The friction of each slide joint: the paper's Coulomb + viscous model, or LuGre (the rig's).

``coulomb`` (the default): the joints' ``frictionloss`` (Af kf) and ``damping`` (B kf), RK4, one physics step
per sample. ``lugre``: a friction-only ``dcmotor`` actuator per slide joint (MuJoCo's ``lugre`` attribute)
carrying the bristle deflection z (m) as its activation, the joint's ``frictionloss`` set to 0; sigma2 is the
joint's ``damping`` in both models, so B reads the same model field. The bristle is stiff: a LuGre plant
integrates with :data:`LUGRE_INTEGRATOR` at :data:`LUGRE_SUBSTEPS` physics steps per control sample. The
true Af, B of a LuGre axis: :func:`identified_af_b`.

(docs/friction.md, "The two models" and "Integration"; the equations: docs/equations.md, section 3.2)
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import mujoco
import numpy as np

from gantry_twin.settings import Count, Range, fmt, rule, validated

#: Names of the friction actuators a LuGre plant adds, per axis name.
FRICTION_ACTUATOR = "{axis}_friction"
#: The integrator and physics steps per control sample of a LuGre plant (docs/friction.md).
LUGRE_INTEGRATOR: Literal["euler", "implicitfast", "rk4"] = "euler"
LUGRE_SUBSTEPS = 8
#: Physical range of the pre-sliding distance Fc / sigma0, m, and of Fs / Fc.
PRESLIDING_M = (0.1e-6, 50.0e-6)
STRIBECK_RATIO = (1.0, 2.0)
#: Range of the Stribeck velocity vs, m/s.
VS_RANGE_M_S = (1.0e-4, 0.05)
#: Fs / Fc when fs_n is not given.
FS_OVER_FC_DEFAULT = 1.3

INTEGRATORS = {
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
}


@validated("lugre")
class LuGreAxis:
    """LuGre parameters of one axis, SI.

    sigma0_n_m: bristle stiffness, N/m. sigma1_ns_m: bristle damping, N s/m.
    fc_n: Coulomb level, N (None: the joint's frictionloss in models/gantry.xml,
    the paper's Af kf). fs_n: static (break-away) level, N (None: 1.3 Fc).
    vs_m_s: Stribeck velocity, m/s. sigma2_ns_m: viscous coefficient, N s/m
    (None: the joint's damping, the paper's B kf).
    """

    sigma0_n_m: Range(1.0e3, 1.0e10, "N/m") = 1.0e6
    sigma1_ns_m: Range(0.0, 1.0e6, "N s/m") = 300.0
    fc_n: Range(0.0, 1000.0, "N", lo_open=True) | None = None
    fs_n: Range(0.0, 2000.0, "N", lo_open=True) | None = None
    vs_m_s: Range(*VS_RANGE_M_S, "m/s") = 0.005
    sigma2_ns_m: Range(0.0, 1.0e4, "N s/m") | None = None

    def __post_init__(self) -> None:
        fs = self.fs_n if self.fc_n is None or self.fs_n is not None else FS_OVER_FC_DEFAULT * self.fc_n
        problem = None if self.fc_n is None else physical_problem(self.sigma0_n_m, self.fc_n, fs)
        if problem is not None:
            raise rule(*problem)


def physical_problem(sigma0_n_m: float, fc_n: float, fs_n: float | None) -> tuple[str, str] | None:
    """(field, message) if the pre-sliding distance Fc / sigma0 or Fs / Fc is out of its physical range."""
    lo, hi = PRESLIDING_M
    if not lo <= fc_n / sigma0_n_m <= hi:
        return (
            "sigma0_n_m",
            f"the pre-sliding distance Fc / sigma0 must be in [{fmt(lo * 1e6)}, {fmt(hi * 1e6)}] um, "
            f"got {fmt(fc_n / sigma0_n_m * 1e6)} um (Fc = {fmt(fc_n)} N)",
        )
    lo, hi = STRIBECK_RATIO
    if fs_n is not None and not lo <= fs_n / fc_n <= hi:
        return "fs_n", f"the ratio Fs / Fc must be in [{fmt(lo)}, {fmt(hi)}], got {fmt(fs_n)} / {fmt(fc_n)} N"
    return None


@validated("friction")
class Friction:
    """The friction model of both slide joints and how the plant integrates it.

    model: ``coulomb`` (the paper's, models/gantry.xml) or ``lugre``
    (x, y: each axis' parameters). integrator, substeps: MuJoCo's integrator
    and physics steps per 0.2 ms control sample (None: the model's own,
    RK4 and 1 for coulomb, LUGRE_INTEGRATOR and LUGRE_SUBSTEPS for lugre).
    """

    model: Literal["coulomb", "lugre"] = "coulomb"
    x: LuGreAxis = LuGreAxis()
    y: LuGreAxis = LuGreAxis()
    integrator: Literal["rk4", "euler", "implicitfast"] | None = None
    substeps: Count(1, 1000) | None = None

    @property
    def lugre(self) -> bool:
        return self.model == "lugre"

    def integration(self) -> tuple[str | None, int]:
        """(integrator, physics steps per control sample); integrator None: the file's (RK4)."""
        integrator = self.integrator or (LUGRE_INTEGRATOR if self.lugre else None)
        return integrator, self.substeps or (LUGRE_SUBSTEPS if self.lugre else 1)


class LuGreParameters(NamedTuple):
    """One axis' compiled LuGre parameters, SI: N/m, N s/m, N, N, m/s, N s/m."""

    sigma0_n_m: float
    sigma1_ns_m: float
    fc_n: float
    fs_n: float
    vs_m_s: float
    sigma2_ns_m: float


class FrictionError(ValueError):
    """A friction setting that is out of range only once the model is known: ``field`` and ``message``."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field, self.message = field, message


def apply_friction(spec: mujoco.MjSpec, friction: Friction, axes: tuple[str, ...]) -> None:
    """Put ``friction`` and its integration (:meth:`Friction.integration`) into the gantry's spec.

    LuGre: per slide joint (named by ``axes``), its frictionloss to 0 and a
    friction-only dcmotor ``<axis>_friction`` after every other actuator (the
    control and disturbance motors keep their indices and ctrl slots). The
    model file's timestep stays the control sample: the caller divides it into the
    sub-steps (:class:`gantry_twin.plant.model.Plant`).
    """
    integrator, _ = friction.integration()
    if friction.lugre:
        for axis in axes:
            given: LuGreAxis = getattr(friction, axis)
            joint = spec.joint(axis)
            fc = float(joint.frictionloss) if given.fc_n is None else given.fc_n
            fs = FS_OVER_FC_DEFAULT * fc if given.fs_n is None else given.fs_n
            problem = physical_problem(given.sigma0_n_m, fc, fs)
            if problem is not None:
                raise FrictionError(f"friction.{axis}.{problem[0]}", problem[1])
            joint.frictionloss = 0.0
            if given.sigma2_ns_m is not None:
                joint.damping = [given.sigma2_ns_m, *joint.damping[1:]]
            motor = spec.add_actuator(name=FRICTION_ACTUATOR.format(axis=axis), target=axis)
            motor.trntype = mujoco.mjtTrn.mjTRN_JOINT
            motor.set_to_dcmotor(
                motorconst=[0.0, 0.0],
                resistance=1.0,
                lugre=[given.sigma0_n_m, given.sigma1_ns_m, fc, fs, given.vs_m_s],
                ctrlspec=int(mujoco.mjtCtrlInput.mjINPUT_NONE),
            )
            motor.gear = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]  # the default class' gear is the motors' 69 N/V
            motor.ctrllimited = 0
            motor.damping = [0.0, 0.0, 0.0]  # sigma2 is the joint's damping (see the module docstring)
    if integrator is not None:
        spec.option.integrator = INTEGRATORS[integrator]


def friction_actuators(model: mujoco.MjModel, axes: tuple[str, ...]) -> np.ndarray:
    """Actuator id of each axis' LuGre friction actuator, -1 where the axis has none."""
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, FRICTION_ACTUATOR.format(axis=a)) for a in axes]
    return np.array(ids, dtype=np.int64)


def check_bristle_damping(model: mujoco.MjModel, actuators: np.ndarray, masses_kg: np.ndarray, axes: tuple) -> None:
    """sigma1 at most the critical damping 2 sqrt(sigma0 M) of the bristle carrying the axis' mass M."""
    for axis, actuator, mass in zip(axes, actuators, masses_kg, strict=True):
        if actuator < 0:
            continue
        p = lugre_parameters(model, int(actuator), 0)
        critical = 2.0 * math.sqrt(p.sigma0_n_m * mass)
        if p.sigma1_ns_m > critical:
            raise FrictionError(
                f"friction.{axis}.sigma1_ns_m",
                f"must be at most the critical damping 2 sqrt(sigma0 M) = {fmt(critical)} N s/m "
                f"(M = {fmt(mass)} kg), got {fmt(p.sigma1_ns_m)}",
            )


def lugre_parameters(model: mujoco.MjModel, actuator: int, dof: int) -> LuGreParameters:
    """The compiled LuGre parameters of friction actuator ``actuator`` on DOF ``dof`` (sigma2: its damping)."""
    sigma0, sigma1 = model.actuator_dynprm[actuator, 5:7]
    fc, fs, vs = model.actuator_biasprm[actuator, 3:6]
    return LuGreParameters(float(sigma0), float(sigma1), float(fc), float(fs), float(vs), float(model.dof_damping[dof]))


def stribeck_n(p: LuGreParameters, v_m_s: np.ndarray | float) -> np.ndarray:
    """g(v) = Fc + (Fs - Fc) exp(-(v / vs)^2), N."""
    v = np.asarray(v_m_s, dtype=float)
    return p.fc_n + (p.fs_n - p.fc_n) * np.exp(-((v / p.vs_m_s) ** 2))


def steady_force_n(p: LuGreParameters, v_m_s: np.ndarray | float) -> np.ndarray:
    """LuGre's friction force sliding steadily at v, N: sign(v) g(v) + sigma2 v."""
    v = np.asarray(v_m_s, dtype=float)
    return np.sign(v) * stribeck_n(p, v) + p.sigma2_ns_m * v


def steady_bristle_m(p: LuGreParameters, v_m_s: float) -> float:
    """The bristle deflection of steady sliding at v, m: sign(v) g(v) / sigma0 (0 at rest).

    With the C library's ``exp`` (``math``'s, not numpy's, whose last bits depend on the CPU): the same start on
    every machine, and in the native plant FMU's C (src/gantry_twin/fmi/native/model.c)."""
    v = float(v_m_s)
    if v == 0.0:
        return 0.0
    r = v / p.vs_m_s
    g = p.fc_n + (p.fs_n - p.fc_n) * math.exp(-(r * r))
    return (g if v > 0.0 else -g) / p.sigma0_n_m


#: The axis speed amplitude of the paper's identification, m/s: the circle's 0.4 m/s (5.1), the
#: calibration contour (docs/friction.md, "True parameters").
IDENTIFICATION_PEAK_M_S = 0.4
#: Samples of the identification's speed distribution.
_IDENTIFICATION_POINTS = 2000


def stribeck_fit(vs_m_s: float, peak_m_s: float = IDENTIFICATION_PEAK_M_S) -> tuple[float, float]:
    """(a, b): the least-squares fit a + b v of the Stribeck shape exp(-(v / vs)^2) over the speeds of an axis
    moving sinusoidally with amplitude ``peak_m_s`` (v = peak |cos theta|, theta uniform: each speed weighted
    by the time the axis spends at it, as on the paper's contours)."""
    theta = (np.arange(_IDENTIFICATION_POINTS) + 0.5) * (0.5 * math.pi / _IDENTIFICATION_POINTS)
    v = peak_m_s * np.cos(theta)
    shape = np.exp(-((v / vs_m_s) ** 2))
    (a, b), *_ = np.linalg.lstsq(np.column_stack([np.ones_like(v), v]), shape, rcond=None)
    return float(a), float(b)


def identified_af_b(
    fc_n: np.ndarray | float, fs_n: np.ndarray | float, vs_m_s: float, sigma2_ns_m: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """The paper's (Af, B) of a LuGre axis, SI (N, N s/m): the least-squares fit of Af sign(v) + B v to the
    steady friction sign(v) g(v) + sigma2 v (:func:`steady_force_n`) over the identification's speeds.

    The fit is linear in Fc, Fs - Fc and sigma2: Af = Fc + (Fs - Fc) a, B = sigma2 + (Fs - Fc) b with
    (a, b) from :func:`stribeck_fit`. Divide by the motor gear (N/V) for volt units.
    """
    a, b = stribeck_fit(vs_m_s)
    bump = np.asarray(fs_n, dtype=float) - np.asarray(fc_n, dtype=float)
    return np.asarray(fc_n, dtype=float) + bump * a, np.asarray(sigma2_ns_m, dtype=float) + bump * b
