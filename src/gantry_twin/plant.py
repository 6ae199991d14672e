"""The machine: compile the MJCF gantry, attach payloads, read the true parameters.

`models/gantry.xml` is the single source of physical truth. The paper's
parameter vector theta (volt units) is *computed* from the compiled model,
never typed a second time (docs/equations.md, the plant).

Axis convention of the whole package: index 0 = X (axis 1, top), index 1 = Y
(axis 2, bottom, carries X). MuJoCo orders the DOFs parent first (Y, then X);
:class:`Plant` hides that behind ``qpos_index``/``dof_index``.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Literal, get_args

import mujoco
import numpy as np

from gantry_twin.friction import (
    Friction,
    LuGreParameters,
    apply_friction,
    check_bristle_damping,
    friction_actuators,
    identified_af_b,
    lugre_parameters,
    steady_bristle_m,
)
from gantry_twin.settings import Range, Vector, validated

#: An axis by name; AXES: the names in the package's order (index 0 = X, 1 = Y).
Axis = Literal["x", "y"]
AXES: tuple[str, str] = get_args(Axis)
#: Names of the eight entries of theta (paper section 2, property P3).
THETA_NAMES: tuple[str, ...] = ("M1", "M2", "B1", "B2", "Af1", "Af2", "dN1", "dN2")
#: Units of the entries of theta, in THETA_NAMES' order (paper section 2: volts per unit of the
#: axis' acceleration, velocity, friction shape and constant).
THETA_UNITS: tuple[str, ...] = ("V/(m/s^2)", "V/(m/s^2)", "V/(m/s)", "V/(m/s)", "V", "V", "V", "V")
#: Largest payload mass accepted, kg. The paper's estimator bounds (theta_max)
#: cover payloads up to about 5.5 kg; heavier loads run but the estimates of
#: M1, M2 then sit on their upper bounds.
PAYLOAD_MAX_KG = 20
#: Payload offsets from the mount site are limited to the X slider's top plate
#: (metres, per component); the offset does not change a slide joint's mass.
PAYLOAD_OFFSET_MAX_M = (0.10, 0.10, 0.20)
#: A payload mass, kg.
PayloadMass = Range(0.0, PAYLOAD_MAX_KG, "kg")
#: A payload's centre of mass from the mount site (x, y, z), m.
PayloadOffset = Vector(tuple(Range(-limit, limit, "m") for limit in PAYLOAD_OFFSET_MAX_M), "xyz")


def default_model_path() -> Path:
    """Path of the shipped MJCF file (``models/gantry.xml``)."""
    packaged = resources.files("gantry_twin") / "models" / "gantry.xml"
    if packaged.is_file():
        return Path(str(packaged))
    return Path(__file__).resolve().parents[2] / "models" / "gantry.xml"


@validated("payload")
class Payload:
    """A payload body on the X carriage.

    mass_kg: 0 means no payload; the paper's Set 2 uses 5 kg.
    offset_m: position of its centre of mass relative to the ``payload_mount``
    site (metres).
    """

    mass_kg: PayloadMass = 0.0
    offset_m: PayloadOffset = (0.0, 0.0, 0.05)


@validated("plant")
class PlantSettings:
    """How the machine departs from models/gantry.xml's defaults in a scenario.

    file: an MJCF model in place of models/gantry.xml (e.g. ``gantry-twin
    identify``'s plant.xml), relative to the scenario file; None: the shipped
    model. friction: its friction model (:mod:`gantry_twin.friction`), applied
    to that model.
    """

    file: str | None = None
    friction: Friction = Friction()


def build_spec(
    payload: Payload | None = None,
    model_path: Path | None = None,
    payload_body: bool = False,
    friction: Friction | None = None,
) -> mujoco.MjSpec:
    """The gantry as an editable MjSpec, with a payload body if one is given and the friction model.

    payload_body: add the body even for a 0 kg payload (MuJoCo accepts a
    massless welded body), so that a run can change its mass (a pick-up).
    friction: see :mod:`gantry_twin.friction` (None: the file's Coulomb
    friction, unchanged). The model file's timestep stays the control sample.
    """
    spec = mujoco.MjSpec.from_file(str(model_path or default_model_path()))
    apply_friction(spec, friction or Friction(), AXES)
    if payload is None and payload_body:
        payload = Payload()
    if payload is not None and (payload.mass_kg > 0.0 or payload_body):
        mount = spec.site("payload_mount")
        carriage = spec.body("x_carriage")
        body = carriage.add_body(name="payload", pos=np.asarray(mount.pos) + np.asarray(payload.offset_m))
        body.explicitinertial = True
        body.mass = payload.mass_kg
        # A steel block, 10 cm square, of the given mass: its rotational
        # inertia is irrelevant to slide joints but keeps the body physical.
        side = 0.1
        height = max(payload.mass_kg / (7850.0 * side * side), 0.005)
        i_xy = payload.mass_kg * (side**2 + height**2) / 12.0
        body.inertia = [i_xy, i_xy, payload.mass_kg * 2 * side**2 / 12.0]
        body.add_geom(
            name="payload_box",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[side / 2, side / 2, height / 2],
            rgba=[0.3, 0.7, 0.3, 1.0],
            mass=0.0,
        )
    return spec


class Plant:
    """The compiled gantry: model, data and the named indices the twin needs."""

    def __init__(
        self,
        payload: Payload | None = None,
        model_path: Path | None = None,
        payload_body: bool = False,
        friction: Friction | None = None,
    ) -> None:
        """payload_body: always build the payload body (even at 0 kg) so its mass can change during a run.

        friction: the friction model (:mod:`gantry_twin.friction`; None: the
        file's Coulomb friction). Raises :class:`gantry_twin.friction.FrictionError`
        for LuGre parameters outside their physical range.
        """
        self.payload = payload or Payload()
        self.friction = friction or Friction()
        self.spec = build_spec(self.payload, model_path, payload_body, self.friction)
        #: The control sample period Ts, s (the file's timestep); substeps: physics steps per sample.
        self.timestep_s = float(self.spec.option.timestep)
        self.substeps = self.friction.integration()[1]
        if self.substeps != 1:
            self.spec.option.timestep = self.timestep_s / self.substeps
        self.model: mujoco.MjModel = self.spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        joints = [m.joint(name) for name in AXES]
        self.qpos_index = np.array([int(j.qposadr[0]) for j in joints])
        self.dof_index = np.array([int(j.dofadr[0]) for j in joints])
        self.motor_index = np.array([m.actuator(f"{a}_motor").id for a in AXES])
        self.disturbance_index = np.array([m.actuator(f"{a}_disturbance").id for a in AXES])
        #: Actuator id of each axis' LuGre friction actuator (X, Y), -1 for Coulomb friction.
        self.friction_index = friction_actuators(m, AXES)
        check_bristle_damping(m, self.friction_index, moving_masses_kg(m, self.dof_index), AXES)
        #: Body id of the payload, or None if the model has no payload body.
        self.payload_body_id: int | None = m.body("payload").id if self.payload.mass_kg > 0.0 or payload_body else None

    @property
    def gear_n_per_v(self) -> np.ndarray:
        """Force per volt of each control motor (X, Y), N/V."""
        return self.model.actuator_gear[self.motor_index, 0].copy()

    @property
    def ctrl_range_v(self) -> np.ndarray:
        """Control motor ranges (X, Y) as [[lo, hi], [lo, hi]], volts."""
        return self.model.actuator_ctrlrange[self.motor_index].copy()

    def reset(self, q_m: np.ndarray, dq_m_s: np.ndarray) -> None:
        """Put the carriages at q (m) moving at dq (m/s), controls at zero.

        LuGre's bristles start deflected as in steady sliding at dq
        (:func:`gantry_twin.friction.steady_bristle_m`; undeflected at rest).
        """
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[self.qpos_index] = q_m
        self.data.qvel[self.dof_index] = dq_m_s
        for axis, actuator in enumerate(self.friction_index):
            if actuator >= 0:
                p = lugre_parameters(self.model, int(actuator), int(self.dof_index[axis]))
                self.data.act[self.model.actuator_actadr[actuator]] = steady_bristle_m(p, float(dq_m_s[axis]))
        mujoco.mj_forward(self.model, self.data)

    @property
    def q_m(self) -> np.ndarray:
        """True carriage positions (X, Y), metres."""
        return self.data.qpos[self.qpos_index]

    @property
    def dq_m_s(self) -> np.ndarray:
        """True carriage velocities (X, Y), m/s."""
        return self.data.qvel[self.dof_index]

    def lugre_parameters(self) -> list[LuGreParameters | None]:
        """Each axis' compiled LuGre parameters (X, Y), SI; None for an axis with Coulomb friction."""
        return [
            None if a < 0 else lugre_parameters(self.model, int(a), int(d))
            for a, d in zip(self.friction_index, self.dof_index, strict=True)
        ]

    def true_parameters(self) -> np.ndarray:
        """theta of the current model, volt units; see :func:`true_parameters`."""
        return true_parameters(self.model, self.dof_index, self.motor_index, self.friction_index)


def moving_masses_kg(model: mujoco.MjModel, dof_index: np.ndarray) -> np.ndarray:
    """Diagonal of the joint-space inertia (X, Y), kg, from ``mj_fullM``."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    return full[dof_index, dof_index]


def true_parameters(
    model: mujoco.MjModel, dof_index: np.ndarray, motor_index: np.ndarray, friction_index: np.ndarray | None = None
) -> np.ndarray:
    """The paper's theta = [M1, M2, B1, B2, Af1, Af2, dN1, dN2] in volt units.

    Computed from the compiled model: masses from ``mj_fullM``, viscous
    damping from ``dof_damping``, Coulomb level from ``dof_frictionloss``,
    each divided by the motor gear (N/V). An axis with LuGre friction
    (friction_index: its actuator, -1 for none) has the B and Af of the
    paper's identification applied to it (:func:`gantry_twin.friction.identified_af_b`).
    dN is zero: the plant has no nominal disturbance.
    """
    gear = model.actuator_gear[motor_index, 0]
    mass = moving_masses_kg(model, dof_index) / gear
    damping = model.dof_damping[dof_index].copy()
    friction = model.dof_frictionloss[dof_index].copy()
    for axis, actuator in enumerate(() if friction_index is None else friction_index):
        if actuator >= 0:
            p = lugre_parameters(model, int(actuator), int(dof_index[axis]))
            af, b = identified_af_b(p.fc_n, p.fs_n, p.vs_m_s, p.sigma2_ns_m)
            friction[axis], damping[axis] = float(af), float(b)
    return np.concatenate([mass, damping / gear, friction / gear, np.zeros(2)])
