"""A LinuxCNC configuration of the twin's XY machine: its limits, the INI and HAL files, a user's INI read back.

The twin's machine for LinuxCNC (docs/linuxcnc.md): trivkins X Y Z in mm,
joints 0 and 1 are the gantry's X and Y axes, joint 2 a Z that LinuxCNC
plans and the twin ignores (as ``--drop-unsupported`` drops Z words), a
1 ms servo period, immediate homing at the travel's centre (the twin's
machine coordinates have their origin there and no home switch), and the
limits the twin's own planner uses (:func:`gantry_twin.gcode.planner.default_limits`).

A user's INI (``--cnc-ini``) is read for what shapes the motion: ``[TRAJ]``,
``[KINS]``, ``[EMCMOT] SERVO_PERIOD``, ``[AXIS_X]``, ``[AXIS_Y]``, ``[AXIS_Z]``
and ``[JOINT_0..2]``; its HAL files, display and hardware are not used.
Limits the twin's machine cannot follow are refused in one line naming the
key (:class:`CncConfigError`): travel beyond the end stops, an acceleration
beyond the motors' peak force (``(10 V - Af) / M``, the plant in volts,
docs/equations.md) or a speed beyond the steady speed at 10 V
(``(10 V - Af) / B``), a servo period that is not a whole multiple of the
twin's 0.2 ms sample, units other than mm or inch, kinematics other than trivkins.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from gantry_twin.gcode.planner import SPEED_MAX_M_S, AxisLimits, default_limits
from gantry_twin.gcode.program import TRAVEL_HALF_M, TRAVEL_MARGIN_M
from gantry_twin.inputs import InputFileError, read_input_file
from gantry_twin.settings import VOLTS_MAX_V, quote
from gantry_twin.theta import NOMINAL_THETA, per_axis

#: The twin's sample period, ns: a servo period must be a whole multiple of it.
TWIN_PERIOD_NS = 200_000
#: LinuxCNC's servo period in the twin's configuration, ns (1 ms: LinuxCNC's usual servo thread).
SERVO_PERIOD_NS = 1_000_000
#: The INI file's name in a written configuration, and the HAL file's.
INI_NAME = "gantry-twin.ini"
HAL_NAME = "gantry-twin.hal"
#: Largest INI read, bytes.
INI_MAX_BYTES = 256 * 1024
#: Z's travel and limits (mm, mm/s, mm/s^2): only for LinuxCNC's plan of programs with Z moves.
Z_TRAVEL_MM = (-100.0, 100.0)
Z_VELOCITY_MM_S = 1000.0
Z_ACCELERATION_MM_S2 = 10_000.0


class CncConfigError(ValueError):
    """A LinuxCNC configuration the twin cannot use: ``FILE: [SECTION] KEY: what is wrong`` (one line)."""


@dataclass(frozen=True)
class CncMachine:
    """What shapes LinuxCNC's motion of the twin, in LinuxCNC's units (mm, mm/s, mm/s^2, ns).

    travel_mm: (min, max) per axis X, Y; velocity_mm_s and acceleration_mm_s2:
    per axis (X, Y); traj_*: the path's ([TRAJ]); following_error_mm:
    (FERROR at full speed, MIN_FERROR at rest) per joint; source: where each
    number came from (the INI's comments).
    """

    travel_mm: tuple[tuple[float, float], tuple[float, float]]
    velocity_mm_s: tuple[float, float]
    acceleration_mm_s2: tuple[float, float]
    traj_velocity_mm_s: float
    traj_acceleration_mm_s2: float
    servo_period_ns: int = SERVO_PERIOD_NS
    following_error_mm: tuple[float, float] = (1.0, 0.25)
    source: str = "the twin's"

    @property
    def servo_period_s(self) -> float:
        return self.servo_period_ns * 1e-9


def twin_machine() -> CncMachine:
    """The twin's machine with the limits its own planner uses (:func:`gantry_twin.gcode.planner.default_limits`)."""
    limits = default_limits()
    half = tuple(1e3 * (h - TRAVEL_MARGIN_M) for h in TRAVEL_HALF_M)
    velocity = tuple(1e3 * v for v in limits.velocity_m_s)
    accel = tuple(1e3 * a for a in limits.acceleration_m_s2)
    return CncMachine(
        travel_mm=((-half[0], half[0]), (-half[1], half[1])),
        velocity_mm_s=velocity,
        acceleration_mm_s2=accel,
        traj_velocity_mm_s=1e3 * SPEED_MAX_M_S,
        traj_acceleration_mm_s2=max(accel),
    )


def followable(axis: int) -> tuple[float, float]:
    """The largest (speed mm/s, acceleration mm/s^2) the twin's axis can follow at 10 V: (10 - Af) / B and
    (10 - Af) / M of the nominal theta (docs/equations.md, the plant in volts)."""
    m, b, af = (per_axis(NOMINAL_THETA, name)[axis] for name in ("M", "B", "Af"))
    return 1e3 * (VOLTS_MAX_V - af) / b, 1e3 * (VOLTS_MAX_V - af) / m


# ---------------------------------------------------------------------------------------------- writing


def ini_text(
    machine: CncMachine,
    display: str,
    hal_files: tuple[str, ...],
    extra: dict[str, dict[str, str]],
    subroutine_path: str = "",
) -> str:
    """The INI of ``machine``: ``display`` is ``[DISPLAY] DISPLAY``; ``hal_files`` the ``[HAL] HALFILE``s;
    ``extra``: more sections (the twin's own: the offline display's settings); ``subroutine_path``: where
    LinuxCNC's interpreter finds a subroutine file a program calls (``[RS274NGC] SUBROUTINE_PATH``)."""
    (x0, x1), (y0, y1) = machine.travel_mm
    vx, vy = machine.velocity_mm_s
    ax, ay = machine.acceleration_mm_s2
    ferror, min_ferror = machine.following_error_mm
    src = machine.source
    lines = [
        "# LinuxCNC configuration of gantry-twin's XY machine (written by `gantry-twin linuxcnc config`).",
        "# X and Y are the twin's axes (joints 0 and 1); Z (joint 2) is planned by LinuxCNC and ignored by the",
        "# twin, as --drop-unsupported drops Z words, so that programs with Z moves run. Units: mm, s.",
        "# docs/linuxcnc.md says what each number is and where it comes from.",
        "[EMC]",
        "VERSION = 1.1",
        "MACHINE = gantry-twin",
        "DEBUG = 0",
        "[DISPLAY]",
        f"DISPLAY = {display}",
        "CYCLE_TIME = 0.100",
        "POSITION_OFFSET = RELATIVE",
        "POSITION_FEEDBACK = ACTUAL",
        "MAX_FEED_OVERRIDE = 1.0",
        "[TASK]",
        "TASK = milltask",
        "CYCLE_TIME = 0.001",
        "[RS274NGC]",
        "PARAMETER_FILE = gantry-twin.var",
        *([f"SUBROUTINE_PATH = {subroutine_path}"] if subroutine_path else []),
        "[EMCMOT]",
        "EMCMOT = motmod",
        "COMM_TIMEOUT = 1.0",
        "BASE_PERIOD = 0",
        f"# the servo period, ns: {src}; a whole multiple of the twin's 0.2 ms sample",
        f"SERVO_PERIOD = {machine.servo_period_ns}",
        "[EMCIO]",
        "EMCIO = io",
        "CYCLE_TIME = 0.100",
        "TOOL_TABLE = gantry-twin.tbl",
        "[HAL]",
        *(f"HALFILE = {name}" for name in hal_files),
        "[TRAJ]",
        "COORDINATES = X Y Z",
        "LINEAR_UNITS = mm",
        "ANGULAR_UNITS = degree",
        f"# path speed and acceleration limits: {src} (the twin's planner limits each axis; these do not bind)",
        f"DEFAULT_LINEAR_VELOCITY = {machine.traj_velocity_mm_s:.6g}",
        f"MAX_LINEAR_VELOCITY = {machine.traj_velocity_mm_s:.6g}",
        f"DEFAULT_LINEAR_ACCELERATION = {machine.traj_acceleration_mm_s2:.6g}",
        f"MAX_LINEAR_ACCELERATION = {machine.traj_acceleration_mm_s2:.6g}",
        "[KINS]",
        "KINEMATICS = trivkins coordinates=XYZ",
        "JOINTS = 3",
    ]
    axes = (("X", (x0, x1), vx, ax), ("Y", (y0, y1), vy, ay), ("Z", Z_TRAVEL_MM, Z_VELOCITY_MM_S, Z_ACCELERATION_MM_S2))
    for joint, (name, (lo, hi), velocity, accel) in enumerate(axes):
        why = (
            f"{src}: travel: the joint range +-{1e3 * TRAVEL_HALF_M[joint]:g} mm (models/gantry.xml) less the"
            f" {1e3 * TRAVEL_MARGIN_M:g} mm a run keeps from the end stops;"
            f" speed and acceleration as the twin's planner (gcode.planner.default_limits)"
            if name != "Z"
            else "Z: LinuxCNC plans it, the twin ignores it"
        )
        body = [
            f"MAX_VELOCITY = {velocity:.6g}",
            f"MAX_ACCELERATION = {accel:.6g}",
            f"MIN_LIMIT = {lo:.6g}",
            f"MAX_LIMIT = {hi:.6g}",
        ]
        lines += [f"[AXIS_{name}]", f"# {why}", *body]
        lines += [
            f"[JOINT_{joint}]",
            "TYPE = LINEAR",
            *body,
            "# following error, mm (at full speed, at rest): a margin over the twin's tracking error",
            f"FERROR = {ferror:.6g}",
            f"MIN_FERROR = {min_ferror:.6g}",
            "# immediate homing at the travel's centre (the twin's origin; its machine has no home switch)",
            "HOME = 0.0",
            "HOME_OFFSET = 0.0",
            "HOME_SEARCH_VEL = 0",
            "HOME_LATCH_VEL = 0",
            "HOME_SEQUENCE = 0",
        ]
    for section, keys in extra.items():
        lines.append(f"[{section}]")
        lines += [f"{key} = {value}" for key, value in keys.items()]
    return "\n".join(lines) + "\n"


def hal_text(record: bool) -> str:
    """The HAL file: motion in the servo thread, the command looped back as the feedback (LinuxCNC's own
    simulator's wiring: the offline mode records the commands and the twin tracks them afterwards), the estop and
    tool-change loopbacks, and with ``record`` HAL's ``sampler`` on the X and Y joint commands and the program line
    motion runs (``motion.program-line``)."""
    lines = [
        "# HAL of gantry-twin's offline mode (written by gantry-twin): motion's commands looped back as feedback,",
        "# X and Y joint commands sampled at every servo period into HAL's sampler FIFO.",
        "loadrt [KINS]KINEMATICS",
        "loadrt [EMCMOT]EMCMOT servo_period_nsec=[EMCMOT]SERVO_PERIOD num_joints=[KINS]JOINTS",
        "addf motion-command-handler servo-thread",
        "addf motion-controller servo-thread",
        "net xpos joint.0.pos-cmd",
        "net ypos joint.1.pos-cmd",
        *(f"net j{j}-loop joint.{j}.motor-pos-cmd => joint.{j}.motor-pos-fb" for j in range(3)),
        "net estop-loop iocontrol.0.user-enable-out => iocontrol.0.emc-enable-in",
        "net tool-prep-loop iocontrol.0.tool-prepare => iocontrol.0.tool-prepared",
        "net tool-change-loop iocontrol.0.tool-change => iocontrol.0.tool-changed",
    ]
    if record:
        lines += [
            "loadrt sampler depth=16384 cfg=ffs",
            "addf sampler.0 servo-thread",
            "setp sampler.0.enable 0",
            "net xpos => sampler.0.pin.0",
            "net ypos => sampler.0.pin.1",
            "net program-line motion.program-line => sampler.0.pin.2",
        ]
    return "\n".join(lines) + "\n"


#: The live mode's HAL FIFOs: the sampler's columns (X and Y motor commands mm, LinuxCNC's estop chain out, motion
#: enabled, the tag the streamer gives back) and the streamer's (the twin's X and Y errors mm, its X and Y measured
#: positions mm, its ok bit, its heartbeat, its tag).
LIVE_SAMPLER_CFG, LIVE_STREAMER_CFG, LIVE_FIFO_DEPTH = "ffbbs", "ffffbbs", 4096
#: Seconds without a heartbeat from the twin before HAL's watchdog drops LinuxCNC's estop chain.
LIVE_WATCHDOG_S = 0.5


def live_hal_text(twin_command: str) -> str:
    """The live mode's HAL file (docs/linuxcnc.md, "The live mode"): the twin is the machine, loaded with ``loadusr
    twin_command``. Per servo period, in this order: ``streamer.0`` gives the twin's error e (mm) of a past
    command, ``sum2`` makes each joint's feedback ``motor-pos-fb = motor-pos-cmd + e`` (the command motion wrote in
    the previous period: LinuxCNC's following error is then -e) while motion is enabled, and the twin's measured
    position (``mux2``) while it is not (motion then copies the feedback into the command: cmd + e would feed the
    error back into the command, growing with the delay), motion runs, and ``sampler.0`` takes the new
    commands for the twin. ``gantry-twin-run`` enables the sampler and the streamer in the same period (the twin
    sets it once its readers run and the streamer holds its prefill). LinuxCNC's estop chain is closed only while
    the twin says it is ok and HAL's ``watchdog`` sees its heartbeat toggle (a dead twin stops the heartbeat; the
    watchdog starts on the ok bit's rising edge, and once tripped it stays so: LinuxCNC must be restarted)."""
    lines = [
        "# HAL of gantry-twin's live mode (written by `gantry-twin linuxcnc config --live`): the twin is the machine.",
        "# Commands go to the twin through sampler.0 -> halsampler; the twin's errors come back through",
        "# halstreamer -> streamer.0, and each joint's feedback is its command plus the twin's error.",
        "loadrt [KINS]KINEMATICS",
        "loadrt [EMCMOT]EMCMOT servo_period_nsec=[EMCMOT]SERVO_PERIOD num_joints=[KINS]JOINTS",
        f"loadrt streamer depth={LIVE_FIFO_DEPTH} cfg={LIVE_STREAMER_CFG}",
        f"loadrt sampler depth={LIVE_FIFO_DEPTH} cfg={LIVE_SAMPLER_CFG}",
        "loadrt sum2 count=2",
        "loadrt mux2 count=2",
        "loadrt watchdog num_inputs=1",
        "loadrt and2 count=2",
        "addf streamer.0 servo-thread",
        "addf watchdog.set-timeouts servo-thread",
        "addf watchdog.process servo-thread",
        "addf and2.0 servo-thread",
        "addf and2.1 servo-thread",
        "addf sum2.0 servo-thread",
        "addf sum2.1 servo-thread",
        "addf mux2.0 servo-thread",
        "addf mux2.1 servo-thread",
        "addf motion-command-handler servo-thread",
        "addf motion-controller servo-thread",
        "addf sampler.0 servo-thread",
        "net gantry-twin-run sampler.0.enable streamer.0.enable",
        "sets gantry-twin-run 0",
        f"setp watchdog.timeout-0 {LIVE_WATCHDOG_S:g}",
        *(
            line
            for j, axis in enumerate("xy")
            for line in (
                f"net {axis}-cmd joint.{j}.motor-pos-cmd => sampler.0.pin.{j} sum2.{j}.in0",
                f"net {axis}-twin-error streamer.0.pin.{j} => sum2.{j}.in1",
                f"net {axis}-cmd-plus-error sum2.{j}.out => mux2.{j}.in1",
                f"net {axis}-twin-position streamer.0.pin.{j + 2} => mux2.{j}.in0",
                f"net {axis}-fb mux2.{j}.out => joint.{j}.motor-pos-fb",
            )
        ),
        "net motion-enabled motion.motion-enabled => mux2.0.sel mux2.1.sel sampler.0.pin.3",
        "net z-loop joint.2.motor-pos-cmd => joint.2.motor-pos-fb",
        "net estop-out iocontrol.0.user-enable-out => and2.0.in0 sampler.0.pin.2",
        "net twin-ok streamer.0.pin.4 => and2.0.in1 watchdog.enable-in",
        "net twin-heartbeat streamer.0.pin.5 => watchdog.input-0",
        "net estop-and-twin-ok and2.0.out => and2.1.in0",
        "net twin-alive watchdog.ok-out => and2.1.in1",
        "net estop-in and2.1.out => iocontrol.0.emc-enable-in",
        "net twin-tag streamer.0.pin.6 => sampler.0.pin.4",
        "net tool-prep-loop iocontrol.0.tool-prepare => iocontrol.0.tool-prepared",
        "net tool-change-loop iocontrol.0.tool-change => iocontrol.0.tool-changed",
        f"loadusr {twin_command}",
    ]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------- reading


def read_ini(path: str | Path) -> dict[str, dict[str, str]]:
    """A LinuxCNC INI as {section: {key: value}} (a key given twice: its last value; ``#`` and ``;`` lines
    are comments). :class:`CncConfigError` for a file that cannot be read."""
    try:
        text = read_input_file(path, "a LinuxCNC INI file", INI_MAX_BYTES)
    except InputFileError as exc:
        raise CncConfigError(f"{path}: {exc}") from None
    sections: dict[str, dict[str, str]] = {}
    current: dict[str, str] | None = None
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1].strip(), {})
        elif "=" in line and current is not None:
            key, _, value = line.partition("=")
            current[key.strip()] = value.strip()
        else:
            raise CncConfigError(f"{path}:{number}: not a [SECTION] or KEY = VALUE line: {quote(line)}")
    return sections


def machine_from_ini(path: str | Path) -> CncMachine:
    """The :class:`CncMachine` a user's INI asks for, checked against what the twin's machine can follow."""
    ini = read_ini(path)

    def get(section: str, key: str, default: str | None = None) -> str:
        value = ini.get(section, {}).get(key, default)
        if value is None:
            raise CncConfigError(f"{path}: [{section}] {key}: missing; the twin needs it")
        return value

    def number(section: str, key: str, default: float | None = None) -> float:
        text = get(section, key, None if default is None else str(default))
        try:
            return float(text)
        except ValueError:
            raise CncConfigError(f"{path}: [{section}] {key}: {quote(text)} is not a number") from None

    units = get("TRAJ", "LINEAR_UNITS", "mm").lower()
    scale = {"mm": 1.0, "metric": 1.0, "inch": 25.4, "in": 25.4, "imperial": 25.4}.get(units)
    if scale is None:
        raise CncConfigError(f"{path}: [TRAJ] LINEAR_UNITS: {quote(units)}; the twin takes mm or inch")
    coordinates = get("TRAJ", "COORDINATES", "X Y Z").upper().replace(" ", "")
    if not coordinates.startswith("XY"):
        raise CncConfigError(f"{path}: [TRAJ] COORDINATES: {quote(coordinates)}; the twin's machine is X Y (Z)")
    kinematics = get("KINS", "KINEMATICS", "trivkins").split()[0]
    if kinematics != "trivkins":
        raise CncConfigError(f"{path}: [KINS] KINEMATICS: {quote(kinematics)}; the twin's axes are its joints")
    period = number("EMCMOT", "SERVO_PERIOD", SERVO_PERIOD_NS)
    if period < TWIN_PERIOD_NS or period % TWIN_PERIOD_NS:
        raise CncConfigError(
            f"{path}: [EMCMOT] SERVO_PERIOD: {period:g} ns; the twin takes whole multiples of its "
            f"{TWIN_PERIOD_NS} ns sample"
        )
    twin = twin_machine()
    travel, velocity, accel = [], [], []
    for axis, name in enumerate("XY"):
        limits = {}
        for section in (f"AXIS_{name}", f"JOINT_{axis}"):
            for key in ("MIN_LIMIT", "MAX_LIMIT", "MAX_VELOCITY", "MAX_ACCELERATION"):
                if key in ini.get(section, {}):
                    value = number(section, key) * scale
                    limits.setdefault(key, []).append((section, value))
        lo_twin, hi_twin = twin.travel_mm[axis]
        speed_max, accel_max = followable(axis)
        for key, bound, worse in (
            ("MIN_LIMIT", lo_twin, lambda v, b: v < b - 1e-9),
            ("MAX_LIMIT", hi_twin, lambda v, b: v > b + 1e-9),
            ("MAX_VELOCITY", speed_max, lambda v, b: v > b or v <= 0),
            ("MAX_ACCELERATION", accel_max, lambda v, b: v > b or v <= 0),
        ):
            for section, value in limits.get(key, []):
                if worse(value, bound):
                    unit = {"MAX_VELOCITY": f"{units}/s", "MAX_ACCELERATION": f"{units}/s^2"}.get(key, units)
                    allowed = (
                        f"the twin's {name} axis follows 0 < {key} <= {bound / scale:.6g} {unit} (at 10 V)"
                        if key.startswith("MAX_V") or key.startswith("MAX_A")
                        else f"the twin's {name} travel is {lo_twin / scale:.6g} .. {hi_twin / scale:.6g} {unit}"
                    )
                    raise CncConfigError(f"{path}: [{section}] {key}: {value / scale:g} {unit}; {allowed}")
        pick = {key: min(v for _, v in values) if key != "MIN_LIMIT" else max(v for _, v in values)
                for key, values in limits.items()}  # fmt: skip
        travel.append((pick.get("MIN_LIMIT", lo_twin), pick.get("MAX_LIMIT", hi_twin)))
        velocity.append(pick.get("MAX_VELOCITY", twin.velocity_mm_s[axis]))
        accel.append(pick.get("MAX_ACCELERATION", twin.acceleration_mm_s2[axis]))
    traj_v = number("TRAJ", "MAX_LINEAR_VELOCITY", twin.traj_velocity_mm_s / scale) * scale
    traj_a = number("TRAJ", "MAX_LINEAR_ACCELERATION", twin.traj_acceleration_mm_s2 / scale) * scale
    ferror = number("JOINT_0", "FERROR", twin.following_error_mm[0] / scale) * scale
    min_ferror = number("JOINT_0", "MIN_FERROR", twin.following_error_mm[1] / scale) * scale
    return replace(
        twin,
        travel_mm=(travel[0], travel[1]),
        velocity_mm_s=(velocity[0], velocity[1]),
        acceleration_mm_s2=(accel[0], accel[1]),
        traj_velocity_mm_s=traj_v,
        traj_acceleration_mm_s2=traj_a,
        servo_period_ns=int(period),
        following_error_mm=(ferror, min_ferror),
        source=f"from {Path(path).name}",
    )


# ---------------------------------------------------------------------------------------------- a configuration

#: The files :func:`config_files` writes: the INI, the HAL file, the (empty) tool table.
TOOL_TABLE_NAME = "gantry-twin.tbl"


def config_files(
    machine: CncMachine, display: str = "axis", live: tuple[str, dict[str, str]] | None = None
) -> dict[str, str]:
    """A LinuxCNC configuration of ``machine`` (name -> text): run it with ``linuxcnc DIR/gantry-twin.ini``
    (LinuxCNC's own simulator wiring: the command is its feedback), edit its limits and give it back to the
    twin with ``--cnc-ini``. ``live``: (the twin's command line, its ``[GANTRY_TWIN]`` settings): the live mode's
    configuration instead, where the twin is the machine (:func:`live_hal_text`)."""
    if live is not None:
        command, settings = live
        return {
            INI_NAME: ini_text(machine, display, (HAL_NAME,), {"GANTRY_TWIN": settings}),
            HAL_NAME: live_hal_text(command),
            TOOL_TABLE_NAME: "",
        }
    return {
        INI_NAME: ini_text(machine, display, (HAL_NAME,), {}),
        HAL_NAME: hal_text(record=False),
        TOOL_TABLE_NAME: "",
    }


def machine_for(limits: AxisLimits | None) -> CncMachine:
    """The twin's machine with a scenario's planner limits (``contour.limits``; None: the default ones)."""
    machine = twin_machine()
    if limits is None:
        return machine
    return replace(
        machine,
        velocity_mm_s=tuple(1e3 * v for v in limits.velocity_m_s),
        acceleration_mm_s2=tuple(1e3 * a for a in limits.acceleration_m_s2),
        traj_velocity_mm_s=1e3 * max(limits.velocity_m_s),
        traj_acceleration_mm_s2=1e3 * max(limits.acceleration_m_s2),
        source="the scenario's contour.limits",
    )
