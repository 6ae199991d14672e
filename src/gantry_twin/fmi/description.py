"""A controller FMU read and checked against the twin's variable convention, before anything is unpacked or run.

An FMU is a zip archive: ``modelDescription.xml`` (read with fmpy), a shared library per platform under
``binaries/<platform>/`` and optional ``resources/``. :func:`read_controller` checks, in this order, that it is
a regular file of bounded size, a zip, holds a readable ``modelDescription.xml``, is FMI 2.0 with a
co-simulation interface, has a binary for this platform, and that its variables bind to the loop's signals
(:func:`bind`). Each problem is one :class:`FmuError` line naming the file (docs/fmi.md, docs/hostile-input.md).

The convention (docs/fmi.md, "The variable convention"): the loop sets the inputs :data:`INPUT_SIGNALS` (the
measurement and the reference sample of the plug-in interface, SI) and reads the outputs :data:`OUTPUT_SIGNALS`
(the two motor commands, volts). A variable named like a signal is bound to it; ``variables`` maps other names
(``{FMU variable: signal}``). An FMU declares any subset of the inputs and both outputs.
"""

from __future__ import annotations

import math
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gantry_twin.inputs import InputFileError, check_input_file
from gantry_twin.settings import quote, shorten

#: The loop's inputs to a controller FMU, in the order of the signal row the step builds (:mod:`.controller`):
#: the measurement's time s, position m and velocity m/s, then the reference's q_d m, q_d' m/s, q_d'' m/s^2.
INPUT_SIGNALS = (
    "t_s",
    "x_m",
    "y_m",
    "dx_m_s",
    "dy_m_s",
    "x_d_m",
    "y_d_m",
    "dx_d_m_s",
    "dy_d_m_s",
    "ddx_d_m_s2",
    "ddy_d_m_s2",
)
#: The FMU's outputs the loop reads: the motor commands X, Y, volts.
OUTPUT_SIGNALS = ("u_x_v", "u_y_v")

#: Largest FMU file, and largest sum of its members unpacked, bytes: a generated controller is a few MiB.
FMU_MAX_BYTES = 512 * 1024 * 1024
FMU_MAX_UNPACKED_BYTES = 1024 * 1024 * 1024
#: Largest modelDescription.xml, bytes (a large Modelica model's is a few MiB).
DESCRIPTION_MAX_BYTES = 64 * 1024 * 1024
DESCRIPTION = "modelDescription.xml"


class FmuError(ValueError):
    """An FMU that cannot be run as a controller: ``<file name>: <what is wrong>``, one line (short: a scenario's
    error quotes 120 characters of it; the scenario names the whole path)."""

    def __init__(self, path: str | Path, what: str) -> None:
        super().__init__(f"{Path(path).name}: {what}")
        self.path, self.what = str(path), what

    def __reduce__(self) -> tuple:  # pickled whole: raised again in the process that watches a worker
        return (type(self), (self.path, self.what))


def this_platform() -> tuple[str, str]:
    """fmpy's name of this platform (``linux64``) and its shared library suffix (``.so``)."""
    from fmpy import platform, sharedLibraryExtension

    return platform, sharedLibraryExtension


@dataclass(frozen=True)
class Variable:
    """A variable of the FMU the loop touches: its name, value reference and (for a bound input) its signal."""

    name: str
    value_reference: int
    signal: str = ""


@dataclass(frozen=True)
class ControllerFmu:
    """A checked controller FMU: what the loop sets, reads, logs and sets once (parameters, with their values).

    needs_python: built with pythonfmu (its library runs a Python class): it runs on the Python loop.
    """

    path: Path
    fmi_version: str
    model_identifier: str
    guid: str
    generation_tool: str
    needs_python: bool
    inputs: tuple[Variable, ...]
    outputs: tuple[Variable, Variable]
    parameters: tuple[tuple[Variable, float], ...]
    logged: tuple[Variable, ...]
    library: str  # the member of the archive that holds this platform's binary
    settable: tuple[tuple[str, str], ...] = ()  # every Real parameter a scenario may set: (name, start value)

    def mapping_lines(self) -> list[str]:
        """The binding, one line per signal: ``x_m <- FMU input 'pos_x' (vr 1)``; unbound inputs as such."""
        bound = {v.signal: v for v in self.inputs}
        lines = []
        for signal in INPUT_SIGNALS:
            v = bound.get(signal)
            lines.append(
                f"  {signal:<11} -> input {quote(v.name)} (vr {v.value_reference})"
                if v
                else f"  {signal:<11}    (not an input of this FMU)"
            )
        for v in self.outputs:
            lines.append(f"  {v.signal:<11} <- output {quote(v.name)} (vr {v.value_reference})")
        for v, value in self.parameters:
            lines.append(f"  parameter {quote(v.name)} (vr {v.value_reference}) = {value!r}")
        for v in self.logged:
            lines.append(f"  logged {quote(v.name)} (vr {v.value_reference})")
        return lines


def read_controller(
    path: str | Path,
    variables: Mapping[str, str] | None = None,
    parameters: Mapping[str, float] | None = None,
    log_variables: Sequence[str] = (),
) -> ControllerFmu:
    """Read and check a controller FMU (module docstring); FmuError naming the file if it cannot run."""
    path = Path(path)
    try:
        check_input_file(path, "an FMI 2.0 co-simulation FMU (.fmu)", FMU_MAX_BYTES)
    except InputFileError as exc:
        raise FmuError(path, str(exc)) from None
    members = _members(path)
    description = _description(path, members)
    version = str(description.fmiVersion)
    if not version.startswith("2."):
        raise FmuError(path, f"FMI {shorten(version, 12)}; the loop runs FMI 2.0 co-simulation FMUs")
    cs = description.coSimulation
    if cs is None:
        raise FmuError(path, "a Model Exchange-only FMU; the loop runs FMI 2.0 co-simulation FMUs")
    platform, suffix = this_platform()
    library = f"binaries/{platform}/{cs.modelIdentifier}{suffix}"
    if library not in members:
        found = sorted({m.split("/")[1] for m in members if m.startswith("binaries/") and m.count("/") >= 2})
        has = f"it has {shorten(', '.join(found), 40)}" if found else "it has none"
        raise FmuError(path, f"no binary for this platform ({library}; {has})")
    tool = str(description.generationTool or "")
    needs_python = tool.startswith("PythonFMU") or "resources/slavemodule.txt" in members
    inputs, outputs, params, logged = bind(path, description.modelVariables, variables, parameters, log_variables)
    settable = tuple(
        (v.name, str(v.start))
        for v in description.modelVariables
        if v.causality == "parameter" and v.type == "Real" and v.variability in ("fixed", "tunable")
    )
    return ControllerFmu(
        path,
        version,
        cs.modelIdentifier,
        str(description.guid),
        tool,
        needs_python,
        inputs,
        outputs,
        params,
        logged,
        library,
        settable,
    )


def _members(path: Path) -> dict[str, int]:
    """The archive's members and their unpacked sizes; FmuError if it is not a zip or unpacks too large."""
    if not zipfile.is_zipfile(path):
        raise FmuError(path, "not a zip archive, so not an FMU")
    try:
        with zipfile.ZipFile(path) as archive:
            members = {info.filename: info.file_size for info in archive.infolist()}
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise FmuError(path, f"a damaged zip archive ({shorten(str(exc), 80)})") from None
    if sum(members.values()) > FMU_MAX_UNPACKED_BYTES:
        raise FmuError(path, f"unpacks to more than {FMU_MAX_UNPACKED_BYTES >> 20} MiB, the limit for an FMU")
    return members


def _description(path: Path, members: dict[str, int]) -> Any:
    """fmpy's ModelDescription of the archive; FmuError if it is missing or cannot be read."""
    if DESCRIPTION not in members:
        raise FmuError(path, f"no {DESCRIPTION} at the top of the archive, so not an FMU")
    if members[DESCRIPTION] > DESCRIPTION_MAX_BYTES:
        raise FmuError(path, f"{DESCRIPTION} is larger than {DESCRIPTION_MAX_BYTES >> 20} MiB")
    from fmpy import read_model_description

    try:
        return read_model_description(str(path), validate=True)
    except Exception as exc:  # fmpy raises plain Exceptions (schema, XML syntax, missing attributes)
        lines = [line.strip(" -") for line in str(exc).splitlines() if line.strip(" -")]
        # fmpy's "Failed to validate modelDescription.xml:" says less than the problem listed under it
        why = lines[1] if len(lines) > 1 and lines[0].endswith(":") else lines[0] if lines else type(exc).__name__
        raise FmuError(path, f"{DESCRIPTION} cannot be read ({shorten(why, 60)})") from None


def bind(
    path: Path,
    model_variables: Sequence[Any],
    variables: Mapping[str, str] | None,
    parameters: Mapping[str, float] | None,
    log_variables: Sequence[str],
) -> tuple[tuple[Variable, ...], tuple[Variable, Variable], tuple[tuple[Variable, float], ...], tuple[Variable, ...]]:
    """(inputs, outputs, parameters, logged) of the FMU's variables (fmpy ScalarVariables) under the convention
    and the scenario's ``variables`` ({FMU variable: signal}), ``parameters`` ({name: value}) and logged names."""
    by_name = {v.name: v for v in model_variables}
    mapping = dict(variables or {})
    signals = (*INPUT_SIGNALS, *OUTPUT_SIGNALS)
    for name, signal in mapping.items():
        if name not in by_name:
            raise FmuError(path, f"variables: {quote(name)} is not a variable of the FMU{_near(name, by_name)}")
        if signal not in signals:
            raise FmuError(path, f"variables.{shorten(name)}: {quote(signal)} is not a signal (docs/fmi.md lists them)")
    by_signal: dict[str, list[str]] = {}
    for name, signal in mapping.items():
        by_signal.setdefault(signal, []).append(name)
    for signal in signals:  # a variable named as a signal is bound to it, unless it is mapped elsewhere
        if signal in by_name and signal not in mapping and signal not in by_signal:
            by_signal[signal] = [signal]

    inputs = []
    for signal in INPUT_SIGNALS:
        for name in by_signal.get(signal, ()):
            v = by_name[name]
            _expect(path, v, signal, "input")
            inputs.append(Variable(name, int(v.valueReference), signal))
    bound_inputs = {v.name for v in inputs}
    for v in model_variables:
        if v.causality == "input" and v.name not in bound_inputs:
            raise FmuError(path, f"input {quote(v.name)} is bound to no signal; map it in variables (docs/fmi.md)")
    outputs = []
    for signal in OUTPUT_SIGNALS:
        names = by_signal.get(signal, [])
        if not names:
            raise FmuError(path, f"no output for {signal}; name one so or map one in variables")
        if len(names) > 1:
            raise FmuError(path, f"{signal} is mapped from {len(names)} variables; give one")
        v = by_name[names[0]]
        _expect(path, v, signal, "output")
        outputs.append(Variable(v.name, int(v.valueReference), signal))

    params = []
    for name, value in (parameters or {}).items():
        v = by_name.get(name)
        if v is None:
            raise FmuError(path, f"parameters: {quote(name)} is not a variable of the FMU{_near(name, by_name)}")
        if v.causality != "parameter" or v.variability not in ("fixed", "tunable"):
            raise FmuError(path, f"parameters: {quote(name)} is a {v.variability} {v.causality}, not a parameter")
        if v.type != "Real":
            raise FmuError(path, f"parameters: {quote(name)} is {v.type}; only Real parameters are set")
        value = float(value)
        lo, hi = _bound(v.min, -math.inf), _bound(v.max, math.inf)
        if not (math.isfinite(value) and lo <= value <= hi):
            raise FmuError(path, f"parameters.{shorten(name)}: must be in [{lo:g}, {hi:g}] (the FMU's), got {value:g}")
        params.append((Variable(name, int(v.valueReference)), value))

    logged = []
    for name in log_variables:
        v = by_name.get(name)
        if v is None:
            raise FmuError(path, f"log_variables: {quote(name)} is not a variable of the FMU{_near(name, by_name)}")
        if v.type != "Real":
            raise FmuError(path, f"log_variables: {quote(name)} is {v.type}; only Real variables are logged")
        logged.append(Variable(name, int(v.valueReference)))
    return tuple(inputs), (outputs[0], outputs[1]), tuple(params), tuple(logged)


def _bound(text: Any, default: float) -> float:
    """A variable's declared min or max as a number (its absence: ``default``)."""
    try:
        return default if text is None else float(text)
    except (TypeError, ValueError):
        return default


def _expect(path: Path, v: Any, signal: str, causality: str) -> None:
    """A bound variable has the causality its signal needs and is Real."""
    if v.causality != causality:
        raise FmuError(path, f"{quote(v.name)} (bound to {signal}) has causality {v.causality}; expected {causality}")
    if v.type != "Real":
        raise FmuError(path, f"{quote(v.name)} (bound to {signal}) is {v.type}; expected Real")


def _near(name: str, names: Mapping[str, Any]) -> str:
    """'; did you mean ...' for a close name, else ''."""
    import difflib

    close = difflib.get_close_matches(name, list(names), n=1)
    return f"; did you mean {quote(close[0])}?" if close else ""
