"""The machine: compile the MJCF gantry, attach payloads, read the true parameters.

`models/gantry.xml` is the single source of physical truth. The paper's
parameter vector theta (volt units) is *computed* from the compiled model,
never typed a second time (docs/equations.md, the plant).

Two machines are shipped (``plant.model``, docs/rig-plant.md): ``paper``,
models/gantry.xml, the paper's model (eq. (1): Coulomb + viscous friction,
no offset); ``rig``, models/rig.xml, the same machine with the properties
the paper's rig shows and its model leaves out, read from the file's
``<custom>`` numerics: LuGre friction per axis (:mod:`gantry_twin.plant.friction`),
a static input offset dN(q) (:class:`InputOffset`: the paper's dN1, dN2,
theta 7-8, constant plus a part linear in position) and a position-periodic
force ripple (:class:`ForceRipple`, up to three harmonics of one pitch).
The offset and the ripple act through the disturbance motors
(:func:`plant_input_v`, evaluated by the loop each sample at the true
position); the controller never sees them.

Axis convention of the whole package: index 0 = X (axis 1, top), index 1 = Y
(axis 2, bottom, carries X). MuJoCo orders the DOFs parent first (Y, then X);
:class:`Plant` hides that behind ``qpos_index``/``dof_index``.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any, Literal

import mujoco
import numpy as np
from pydantic import model_validator
from pydantic_core import ArgsKwargs

from gantry_twin.inputs import check_input_file
from gantry_twin.paths.contours import Contour
from gantry_twin.plant.effects import (
    Amplifier,
    ForceRipple,
    InputOffset,
    file_properties,
    input_table,
)
from gantry_twin.plant.friction import (
    Friction,
    LuGreParameters,
    apply_friction,
    check_bristle_damping,
    friction_actuators,
    identified_af_b,
    lugre_parameters,
    steady_bristle_m,
)
from gantry_twin.settings import Range, Vector, rule, validated
from gantry_twin.theta import AXES, THETA_NAMES, THETA_UNITS, Axis  # noqa: F401 -- the plant's names for them

#: Largest payload mass accepted, kg. The paper's estimator bounds (theta_max)
#: cover payloads up to about 5.5 kg; heavier loads run but the estimates of
#: M1, M2 then sit on their upper bounds.
PAYLOAD_MAX_KG = 20
#: Largest MJCF model file compiled (models/gantry.xml is 8 KB; meshes are files of their own), bytes.
MODEL_MAX_BYTES = 1 << 20
#: Payload offsets from the mount site are limited to the X slider's top plate
#: (metres, per component); the offset does not change a slide joint's mass.
PAYLOAD_OFFSET_MAX_M = (0.10, 0.10, 0.20)
#: The payload body: a steel block (kg/m^3) of this side (m), at least this high (m) (:func:`build_spec`; the native
#: plant FMU's C builds the same block, src/gantry_twin/fmi/native/model.c).
PAYLOAD_DENSITY_KG_M3, PAYLOAD_SIDE_M, PAYLOAD_MIN_HEIGHT_M = 7850.0, 0.1, 0.005
#: A payload mass, kg.
PayloadMass = Range(0.0, PAYLOAD_MAX_KG, "kg")
#: A payload's centre of mass from the mount site (x, y, z), m.
PayloadOffset = Vector(tuple(Range(-limit, limit, "m") for limit in PAYLOAD_OFFSET_MAX_M), "xyz")


#: The shipped machines (``plant.model``) and their MJCF files in models/.
PLANT_MODELS: dict[str, str] = {"paper": "gantry.xml", "rig": "rig.xml"}
PlantModel = Literal["paper", "rig"]
#: How the shipped machines are named in words.
PLANT_WORDS: dict[str, str] = {"paper": "ideal", "rig": "rig"}
#: The machine a scenario runs on when it names none: the paper's rig (docs/rig-plant.md).
DEFAULT_PLANT_MODEL: PlantModel = "rig"


def default_model_path(model: PlantModel = "paper") -> Path:
    """Path of a shipped MJCF file: ``models/gantry.xml`` (paper) or ``models/rig.xml`` (rig)."""
    name = PLANT_MODELS[model]
    packaged = resources.files("gantry_twin") / "models" / name
    if packaged.is_file():
        return Path(str(packaged))
    return Path(__file__).resolve().parents[3] / "models" / name


def short_label(label: str) -> str:
    """A :attr:`PlantSettings.label` without its file: ``rig plant``, ``ideal plant`` (headers, table rows)."""
    return label.split(" (")[0]


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
    """The machine of a scenario.

    model: the shipped machine, ``rig`` (models/rig.xml, the default: the
    paper's rig as measured, with LuGre friction, a static input offset and a
    force ripple; docs/rig-plant.md) or ``paper`` (models/gantry.xml, the
    paper's ideal model); none when ``file`` is given without it. file: an MJCF model in place of
    the shipped one (e.g. ``gantry-twin identify``'s plant.xml), relative to
    the scenario file. friction, offset, ripple: the friction model
    (:mod:`gantry_twin.plant.friction`), the static input offset and the force
    ripple; None: the model file's own (its numerics, :func:`file_properties`;
    for models/gantry.xml its Coulomb friction, no offset, no ripple). A
    value given replaces the file's whole property.
    """

    model: PlantModel | None = DEFAULT_PLANT_MODEL
    file: str | None = None
    friction: Friction | None = None
    offset: InputOffset | None = None
    ripple: ForceRipple | None = None
    amplifier: Amplifier | None = None

    @model_validator(mode="before")
    @classmethod
    def _a_file_alone_has_no_model(cls, data: Any) -> Any:
        """``file`` given without ``model``: the file is the machine (model none), not the default's."""
        if isinstance(data, dict) and data.get("file") is not None and "model" not in data:
            return {**data, "model": None}
        if isinstance(data, ArgsKwargs) and not data.args and (data.kwargs or {}).get("file") is not None:
            if "model" not in data.kwargs:
                return ArgsKwargs((), {**data.kwargs, "model": None})
        return data

    def __post_init__(self) -> None:
        if self.file is not None and self.model is not None:
            raise rule("file", f"give a model file or model: {self.model}, not both")
        if self.file is None and self.model is None:
            raise rule("model", "give a shipped machine (rig, paper) or a model file")

    @property
    def label(self) -> str:
        """The machine in words, as summaries, printed headers and reports name it: ``rig plant
        (models/rig.xml)``, ``ideal plant (models/gantry.xml)`` or ``plant file NAME``; ``, with plant
        overrides`` when the scenario sets its friction, offset or ripple."""
        if self.file is not None:
            name = f"plant file {Path(self.file).name}"
        else:
            name = f"{PLANT_WORDS[self.model]} plant (models/{PLANT_MODELS[self.model]})"
        given = (self.friction, self.offset, self.ripple)
        return name + (", with plant overrides" if any(v is not None for v in given) else "")


def model_file(model_path: Path | None) -> str:
    """The MJCF file to compile: ``model_path`` through the input door (a regular file of at most
    :data:`MODEL_MAX_BYTES`: a FIFO, a device or a huge file is refused, unopened, with InputFileError, a
    ValueError), or the shipped model."""
    if model_path is None:
        return str(default_model_path())
    check_input_file(model_path, "a MuJoCo model file (MJCF XML)", MODEL_MAX_BYTES)
    return str(model_path)


def build_spec(
    payload: Payload | None = None,
    model_path: Path | None = None,
    payload_body: bool = False,
    friction: Friction | None = None,
) -> mujoco.MjSpec:
    """The gantry as an editable MjSpec, with a payload body if one is given and the friction model.

    payload_body: add the body even for a 0 kg payload (MuJoCo accepts a
    massless welded body), so that a run can change its mass (a pick-up).
    friction: see :mod:`gantry_twin.plant.friction` (None: the file's own, its
    LuGre numerics (:func:`file_properties`) or else its Coulomb friction).
    The model file's timestep stays the control sample.
    """
    spec = mujoco.MjSpec.from_file(model_file(model_path))
    apply_friction(spec, friction or file_properties(spec).friction or Friction(), AXES)
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
        side = PAYLOAD_SIDE_M
        height = max(payload.mass_kg / (PAYLOAD_DENSITY_KG_M3 * side * side), PAYLOAD_MIN_HEIGHT_M)
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
        offset: InputOffset | None = None,
        ripple: ForceRipple | None = None,
        amplifier: Amplifier | None = None,
    ) -> None:
        """payload_body: always build the payload body (even at 0 kg) so its mass can change during a run.

        friction, offset, ripple: the friction model (:mod:`gantry_twin.plant.friction`),
        the static input offset and the force ripple; None: the model file's
        own (:func:`file_properties`; models/gantry.xml: Coulomb friction, no
        offset, no ripple). amplifier: the computation delay and current loop
        (:class:`Amplifier`; None: neither). Raises :class:`gantry_twin.plant.friction.FrictionError`
        for LuGre parameters outside their physical range.
        """
        self.payload = payload or Payload()
        own = file_properties(mujoco.MjSpec.from_file(model_file(model_path)))
        self.friction = friction or own.friction or Friction()
        #: The static input offset dN(q) and the force ripple, applied by the loop (:func:`plant_input_v`).
        self.offset = offset or own.offset or InputOffset()
        self.ripple = ripple or own.ripple or ForceRipple()
        #: The computation delay and the current loop between command and motor (applied by the loop).
        self.amplifier = amplifier or Amplifier()
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
        (:func:`gantry_twin.plant.friction.steady_bristle_m`; undeflected at rest).
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

    @classmethod
    def shipped(cls, model: PlantModel, payload: Payload | None = None, payload_body: bool = False) -> Plant:
        """The shipped machine ``paper`` (models/gantry.xml) or ``rig`` (models/rig.xml) with its own properties."""
        return cls(payload, default_model_path(model), payload_body)

    def input_table(self) -> np.ndarray:
        """The offset and ripple table the loop reads (:func:`input_table`)."""
        return input_table(self.offset, self.ripple)

    def offset_v(self, operating_point_m: np.ndarray | tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """dN (X, Y) at the operating point q (m), volts: the true dN1, dN2 (:class:`OffsetAxis`)."""
        return np.array([getattr(self.offset, a).at_v(float(q)) for a, q in zip(AXES, operating_point_m, strict=True)])

    def true_parameters(self, operating_point_m: np.ndarray | tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """theta of the current model, volt units; see :func:`true_parameters`.

        operating_point_m: where dN(q) is read (the time-mean position of a
        run's contour, :func:`operating_point_m`; the travel centre by default).
        """
        theta = true_parameters(self.model, self.dof_index, self.motor_index, self.friction_index)
        theta[6:8] = self.offset_v(operating_point_m)
        return theta


def operating_point_m(path: Contour, points: int = 3600) -> np.ndarray:
    """The mean position of a contour over one lap at constant rate, m (X, Y): where a linear dN(q) has its mean."""
    phi = (np.arange(points) + 0.5) * (path.period_rad / points)
    return np.asarray(path.derivatives(phi)[0], dtype=float).mean(axis=0)


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
    paper's identification applied to it (:func:`gantry_twin.plant.friction.identified_af_b`).
    dN is zero here: a plant's static input offset is added by
    :meth:`Plant.true_parameters`.
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
