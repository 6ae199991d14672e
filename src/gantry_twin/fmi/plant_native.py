"""Build the native plant FMU: FMI 2.0 co-simulation, C compiled at export against MuJoCo's library.

The C is in ``native/``: ``model.c`` the plant (the machine compiled with MuJoCo's C API, each 0.2 ms sample:
the DAC clip, the disturbance input, the rig's input offset and force ripple, MuJoCo's steps, the encoder),
``fmi2Functions.c`` the FMI 2.0 plumbing (the split of modelica/Reference-FMUs). This module writes what the C
needs to know of the machine into ``config.h`` (:func:`config_header`: the sample period, the sub-steps, the
offset and ripple table, the encoder, each parameter's range and the order :func:`gantry_twin.fmi.plant.build_plant`
checks them in), the machine as one MJCF file (:func:`machine_xml`), ``modelDescription.xml``
(:func:`model_description`), compiles with the machine's C compiler and zips the FMU with the mujoco wheel's
``libmujoco`` and its licence beside the FMU's library, found there through ``$ORIGIN`` (docs/fmi.md, "The plant
as an FMU").
"""

from __future__ import annotations

import importlib.metadata
import os
import shutil
import subprocess
import tempfile
import uuid
import zipfile
from collections.abc import Mapping
from pathlib import Path
from xml.etree.ElementTree import Element, SubElement, indent, tostring

import mujoco

from gantry_twin.fmi.plant import (
    INPUTS,
    OUTPUTS,
    PAYLOAD,
    START,
    descriptions,
    parameter_fields,
)
from gantry_twin.plant import friction
from gantry_twin.plant.effects import RIPPLE_HARMONICS
from gantry_twin.plant.friction import LuGreAxis
from gantry_twin.plant.model import (
    AXES,
    PAYLOAD_DENSITY_KG_M3,
    PAYLOAD_MIN_HEIGHT_M,
    PAYLOAD_SIDE_M,
    Payload,
    Plant,
    PlantModel,
    default_model_path,
)
from gantry_twin.plant.sensing import SensingConfig
from gantry_twin.settings import Allowed

#: The C sources (package data) and the FMU's model identifier (its library: binaries/linux64/GantryPlant.so).
SOURCES = Path(__file__).resolve().parent / "native"
MODEL_IDENTIFIER = "GantryPlant"
#: The machine's MJCF in the FMU's resources/.
MODEL_FILE = "model.xml"
#: No fused multiply-add (numba's code rounds every product: the twin's doubles); only the FMI functions exported.
CFLAGS = ("-O2", "-ffp-contract=off", "-fPIC", "-shared", "-std=gnu11", "-fvisibility=hidden", "-Wall", "-Wextra")
#: Where the FMU's library and MuJoCo's go (the only platform built: Linux x86-64).
PLATFORM = "linux64"
#: Check kinds of config.h (model.c's refuse_out_of_range) and the markers of the LuGre cross-checks.
KIND = {"finite": "GP_ANY_FINITE", "range": "GP_RANGE", "nonnegative": "GP_NONNEGATIVE"}
LUGRE_CHECK = ("GP_CHECK_LUGRE_X", "GP_CHECK_LUGRE_Y")


class NoCompilerError(RuntimeError):
    """No C compiler on this machine (``$CC`` or ``cc``): the native FMU cannot be built here."""


def c_compiler() -> str | None:
    """The C compiler the export uses: ``$CC`` if set, else ``cc``; None if it is not found."""
    return shutil.which(os.environ.get("CC") or "cc")


def mujoco_library() -> Path:
    """The mujoco wheel's C library (``libmujoco.so.<version>``, its soname)."""
    found = sorted(Path(mujoco.__file__).parent.glob("libmujoco.so.*"))
    if not found:
        raise RuntimeError(f"the mujoco package at {Path(mujoco.__file__).parent} has no libmujoco.so.*")
    return found[0]


def mujoco_licences() -> list[Path]:
    """The mujoco wheel's licence files (its LICENSE, Apache-2.0, and the notices of what it bundles)."""
    files = importlib.metadata.files("mujoco") or []
    found = [Path(f.locate()) for f in files if "/licenses/" in f.as_posix() or f.name in ("LICENSE", "LICENSE.txt")]
    if not found:
        raise RuntimeError("the mujoco package carries no licence file to ship beside its library")
    return found


def machine_xml(model: PlantModel) -> str:
    """The machine as one MJCF file: ``model``'s file as :class:`~gantry_twin.plant.model.Plant` builds it (its
    friction model, LuGre actuators on the rig, the integrator and the sub-step timestep), with the payload body
    (at 0 kg) for model.c to give its mass. MuJoCo writes 6 significant digits: model.c sets every value that has
    more (the parameters, the timestep) from the doubles in config.h and the FMU's variables."""
    plant = Plant(Payload(), default_model_path(model), payload_body=True)
    return plant.spec.to_xml()


def _c(x: float) -> str:
    """A double as a C literal that reads back as the same double."""
    return repr(float(x))


def _string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _range(allowed: Allowed) -> tuple[str, str]:
    """(kind, the C initialiser's bounds) of a settings Range."""
    return "range", f"{_c(allowed.lo)}, {_c(allowed.hi)}, {int(allowed.lo_open)}"


def _allowed(cls: type, field: str) -> Allowed:
    """The :class:`~gantry_twin.settings.Allowed` of a settings class's Range field (Optional or not)."""
    info = cls.__pydantic_fields__[field]
    found = [m for m in info.metadata if isinstance(m, Allowed)]
    for arg in getattr(info.annotation, "__args__", ()):
        found += [m for m in getattr(arg, "__metadata__", ()) if isinstance(m, Allowed)]
    return found[0]


def parameter_checks(lugre: bool) -> list[tuple[str, str, float, float, bool, str]]:
    """Each parameter's check: (name, kind, lo, hi, lo_open, the words of its error), in the FMU's order.

    The ranges are the settings' own (:class:`~gantry_twin.plant.model.Payload`,
    :class:`~gantry_twin.plant.friction.LuGreAxis`); a Coulomb plant's friction must be a finite number >= 0
    (:func:`gantry_twin.fmi.plant.build_plant`); the start state finite.
    """
    payload = _allowed(Payload, "mass_kg")
    checks = [(PAYLOAD, "range", payload.lo, payload.hi, payload.lo_open, f"must be in {payload.text}")]
    checks += [(name, "finite", 0.0, 0.0, False, "must be a finite number") for name in START]
    for axis in AXES:
        for field in parameter_fields(lugre):
            name = f"friction.{axis}.{field}"
            if lugre:
                a = _allowed(LuGreAxis, field)
                checks.append((name, "range", a.lo, a.hi, a.lo_open, f"must be in {a.text}"))
            else:
                checks.append((name, "nonnegative", 0.0, 0.0, False, "must be a finite number >= 0"))
    return checks


def check_order(lugre: bool) -> list[str]:
    """Value references (as C expressions) in the order build_plant refuses them: the payload, then per axis its
    friction fields (LuGreAxis's order, then its cross-checks), then the start state (finite)."""
    names = [v[0] for v in parameter_checks(lugre)]
    order = [str(names.index(PAYLOAD))]
    fields = list(LuGreAxis.__pydantic_fields__) if lugre else ["fc_n", "sigma2_ns_m"]
    for i, axis in enumerate(AXES):
        order += [str(names.index(f"friction.{axis}.{field}")) for field in fields]
        order += [LUGRE_CHECK[i]] if lugre else []
    return order + [str(names.index(name)) for name in START]


def config_header(model: PlantModel, values: Mapping[str, float], guid: str) -> str:
    """config.h: the machine's constants and the variables' table for model.c and fmi2Functions.c."""
    plant = Plant.shipped(model)
    lugre = plant.friction.lugre
    sensing = SensingConfig()
    checks = parameter_checks(lugre)
    names = [c[0] for c in checks] + list(INPUTS) + list(OUTPUTS)
    starts = [float(values[c[0]]) for c in checks] + [0.0] * (len(INPUTS) + len(OUTPUTS))
    table = plant.input_table()
    rows = ", ".join("{" + ", ".join(_c(x) for x in row) + "}" for row in table)
    lines = [
        "/* Written by gantry-twin's fmu export (src/gantry_twin/fmi/plant_native.py) for this FMU alone. */",
        f"#define GP_GUID {_string(guid)}",
        f"#define GP_MODEL_FILE {_string(MODEL_FILE)}",
        f"#define GP_LUGRE {int(lugre)}",
        f"#define GP_SAMPLE_PERIOD_S {_c(plant.timestep_s)}",
        f"#define GP_SUBSTEPS {plant.substeps}",
        f"#define GP_QUANTIZE {int(sensing.quantize)}",
        f"#define GP_RESOLUTION_M {_c(sensing.resolution_m)}",
        f"#define GP_VELOCITY_BY_DIFFERENCE {int(sensing.velocity_by_difference)}",
        f"#define GP_RIPPLE_HARMONICS {RIPPLE_HARMONICS}",
        f"#define GP_PAYLOAD_SIDE_M {_c(PAYLOAD_SIDE_M)}",
        f"#define GP_PAYLOAD_DENSITY_KG_M3 {_c(PAYLOAD_DENSITY_KG_M3)}",
        f"#define GP_PAYLOAD_MIN_HEIGHT_M {_c(PAYLOAD_MIN_HEIGHT_M)}",
        f"#define GP_PRESLIDING_MIN_M {_c(friction.PRESLIDING_M[0])}",
        f"#define GP_PRESLIDING_MAX_M {_c(friction.PRESLIDING_M[1])}",
        f"#define GP_STRIBECK_MIN {_c(friction.STRIBECK_RATIO[0])}",
        f"#define GP_STRIBECK_MAX {_c(friction.STRIBECK_RATIO[1])}",
        f"#define GP_FRICTION_ACTUATOR {_string(friction.FRICTION_ACTUATOR.format(axis='%s'))}",
        f"static const double GP_INPUT_TABLE[2][{table.shape[1]}] = {{{rows}}};",
        f"#define GP_N_PARAMETERS {len(checks)}",
        f"#define GP_N_VARIABLES {len(names)}",
        f"#define GP_VR_PAYLOAD {names.index(PAYLOAD)}",
        f"#define GP_VR_START {names.index(START[0])}",
        f"#define GP_VR_U {names.index('u_x_v')}",
        f"#define GP_VR_D {names.index('d_x_v')}",
        f"#define GP_VR_OUTPUTS {names.index(OUTPUTS[0])}",
    ]
    for field in ("fc_n", "sigma2_ns_m", "fs_n", "vs_m_s", "sigma0_n_m", "sigma1_ns_m"):
        refs = [names.index(n) if (n := f"friction.{a}.{field}") in names else -1 for a in AXES]
        macro = "GP_VR_" + field.split("_")[0].upper()
        lines.append(f"static const int {macro}[2] = {{{refs[0]}, {refs[1]}}};")
    lines += [
        "enum { GP_ANY_FINITE, GP_RANGE, GP_NONNEGATIVE };",
        "enum { GP_CHECK_LUGRE_X = -1, GP_CHECK_LUGRE_Y = -2 };",
        "typedef struct { const char *name; int kind; double lo, hi; int lo_open; const char *allowed; } GpParameter;",
        "static const GpParameter GP_PARAMETERS[GP_N_PARAMETERS] = {",
        *(
            f"    {{{_string(n)}, {KIND[k]}, {_c(lo)}, {_c(hi)}, {int(op)}, {_string(words)}}},"
            for n, k, lo, hi, op, words in checks
        ),
        "};",
        f"static const int GP_CHECK_ORDER[] = {{{', '.join(check_order(lugre))}}};",
        "#define GP_N_CHECKS ((int)(sizeof GP_CHECK_ORDER / sizeof GP_CHECK_ORDER[0]))",
        f"static const double GP_START[GP_N_VARIABLES] = {{{', '.join(_c(x) for x in starts)}}};",
    ]
    return "\n".join(["#ifndef GANTRY_PLANT_CONFIG_H", "#define GANTRY_PLANT_CONFIG_H", *lines, "#endif", ""])


def model_description(
    values: Mapping[str, float], guid: str, description: str, version: str, sample_period_s: float
) -> str:
    """modelDescription.xml (FMI 2.0): the Python FMU's variables, in its order and with its value references."""
    root = Element(
        "fmiModelDescription",
        fmiVersion="2.0",
        modelName=MODEL_IDENTIFIER,
        guid=guid,
        description=description,
        author="gantry-twin",
        version=version,
        license="MIT (gantry-twin's code); Apache-2.0 (MuJoCo, binaries/linux64/libmujoco.so.*)",
        generationTool=f"gantry-twin {version} (fmu export, native)",
        variableNamingConvention="structured",
        numberOfEventIndicators="0",
    )
    SubElement(
        root,
        "CoSimulation",
        modelIdentifier=MODEL_IDENTIFIER,
        canHandleVariableCommunicationStepSize="true",
        canGetAndSetFMUstate="true",
        canSerializeFMUstate="true",
        canNotUseMemoryManagementFunctions="true",
    )
    categories = SubElement(root, "LogCategories")
    for status in ("Warning", "Error"):
        SubElement(categories, "Category", name=f"logStatus{status}", description=f"messages of status fmi2{status}")
    SubElement(root, "DefaultExperiment", startTime="0.0", stepSize=repr(sample_period_s))
    variables = SubElement(root, "ModelVariables")
    texts = descriptions(values)
    kinds = (
        ("parameter", "fixed", texts["parameter_descriptions"]),
        ("input", "continuous", texts["input_descriptions"]),
        ("output", "continuous", texts["output_descriptions"]),
    )
    outputs, reference = [], 0
    for causality, variability, named in kinds:
        for name, text in named.items():
            attributes = {"name": name, "valueReference": str(reference), "description": text}
            attributes |= {"causality": causality, "variability": variability}
            variable = SubElement(variables, "ScalarVariable", attributes)
            start = {} if causality == "output" else {"start": repr(float(values.get(name, 0.0)))}
            SubElement(variable, "Real", start)
            reference += 1
            if causality == "output":
                outputs.append(str(reference))
    structure = SubElement(root, "ModelStructure")
    for part in ("Outputs", "InitialUnknowns"):
        unknowns = SubElement(structure, part)
        for index in outputs:
            SubElement(unknowns, "Unknown", index=index)
    indent(root, "  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="unicode") + "\n"


def compile_library(work: Path, header: str) -> Path:
    """Compile model.c and fmi2Functions.c with config.h into ``work/GantryPlant.so``, linked to the wheel's
    libmujoco with ``$ORIGIN`` as its run path (NoCompilerError without a compiler; RuntimeError with the
    compiler's first error line)."""
    compiler = c_compiler()
    if compiler is None:
        raise NoCompilerError(f"no C compiler found ({os.environ.get('CC') or 'cc'})")
    import fmpy

    (work / "config.h").write_text(header, encoding="utf-8")
    library = work / f"{MODEL_IDENTIFIER}.so"
    include = (work, SOURCES, Path(fmpy.__file__).parent / "c-code", Path(mujoco.__file__).parent / "include")
    command = [compiler, *CFLAGS, *(f"-I{p}" for p in include)]
    command += [str(SOURCES / "model.c"), str(SOURCES / "fmi2Functions.c"), str(mujoco_library())]
    command += ["-Wl,-rpath,$ORIGIN", "-Wl,--no-undefined", "-lm", "-o", str(library)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300, check=False)
    if done.returncode != 0 or not library.is_file():
        errors = [line for line in done.stderr.splitlines() if "error" in line] or done.stderr.splitlines() or ["?"]
        raise RuntimeError(f"{Path(compiler).name} failed to compile the plant FMU: {errors[0]}")
    return library


def build_native(
    model: PlantModel, values: Mapping[str, float], description: str, version: str, sample_period_s: float
) -> bytes:
    """The native plant FMU of ``model`` with the parameters' defaults ``values``, as the bytes of its zip."""
    xml = machine_xml(model)
    guid = "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, f"gantry-twin/{version}/{model}/{sorted(values.items())}")) + "}"
    header = config_header(model, values, guid)
    with tempfile.TemporaryDirectory(prefix="gantry_native_fmu_") as work:
        library = compile_library(Path(work), header)
        binaries = f"binaries/{PLATFORM}"
        with zipfile.ZipFile(Path(work) / "plant.fmu", "w", zipfile.ZIP_DEFLATED) as fmu:
            fmu.writestr("modelDescription.xml", model_description(values, guid, description, version, sample_period_s))
            fmu.write(library, f"{binaries}/{library.name}")
            fmu.write(mujoco_library(), f"{binaries}/{mujoco_library().name}")
            for licence in mujoco_licences():
                fmu.write(licence, f"{binaries}/mujoco-{licence.name}")
            fmu.writestr(f"resources/{MODEL_FILE}", xml)
        return (Path(work) / "plant.fmu").read_bytes()
