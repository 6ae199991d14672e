"""Build the plant FMU: an FMI 2.0 co-simulation FMU of the rig or the paper's plant, with pythonfmu.

The FMU holds, in ``resources/``, :mod:`gantry_twin.fmi.plant_slave` (the ``Fmi2Slave``), its settings
(:data:`~gantry_twin.fmi.plant_slave.SETTINGS_FILE`: the machine, the parameters' defaults, the sample period,
the gantry-twin version) and the machine's MJCF files; pythonfmu's binary runs the slave in the Python that
loads the FMU, which needs gantry-twin installed (docs/fmi.md, "The plant as an FMU").
"""

from __future__ import annotations

import contextlib
import json
import shutil
import sys
import tempfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

from gantry_twin.fmi import plant_slave
from gantry_twin.fmi.plant import MEASURED, PAYLOAD, START, TRUE, build_plant, default_parameters
from gantry_twin.outputs.files import atomic_write
from gantry_twin.plant.model import PLANT_MODELS, PLANT_WORDS, Payload, Plant, PlantModel, default_model_path
from gantry_twin.run import package_version

#: Every MJCF file a machine's file includes (models/rig.xml includes models/gantry.xml).
MODEL_FILES: dict[str, tuple[str, ...]] = {"paper": ("gantry.xml",), "rig": ("rig.xml", "gantry.xml")}


@dataclass(frozen=True)
class ExportedPlant:
    """What :func:`export_plant` wrote: the file, the machine, the parameters' defaults and the requirement."""

    path: Path
    model: PlantModel
    parameters: dict[str, float]
    requirement: str
    sample_period_s: float


def requirement(version: str) -> str:
    """What the FMU needs to run, in words (the FMU's description and ``fmu export``'s output say it)."""
    return (
        f"needs a Python (3.11 or later) with gantry-twin {version} installed, loaded in the importing process: "
        "pythonfmu's binary calls Python at every fmi2DoStep"
    )


#: The friction parameters in words, with their units.
FRICTION_WORDS = {
    "fc_n": "Coulomb level, N",
    "sigma2_ns_m": "viscous coefficient, N s/m",
    "fs_n": "LuGre static (break-away) level, N",
    "vs_m_s": "LuGre Stribeck velocity, m/s",
    "sigma0_n_m": "LuGre bristle stiffness, N/m",
    "sigma1_ns_m": "LuGre bristle damping, N s/m",
}


def _descriptions(parameters: Mapping[str, float]) -> dict[str, dict[str, str]]:
    """Every variable's description, by kind (the slave registers them in this order)."""
    params = {PAYLOAD: "payload on the X carriage, kg (0 to 20)"}
    params.update(zip(START, ("start position X, m", "start position Y, m", "start velocity X, m/s",
                              "start velocity Y, m/s"), strict=True))  # fmt: skip
    for name in parameters:
        if name.startswith("friction."):
            _, axis, field = name.split(".")
            what, unit = FRICTION_WORDS[field].split(", ")
            params[name] = f"{what} of axis {axis.upper()}, {unit}"
    inputs = {
        "u_x_v": "motor command X, V (clipped to the DAC's +-10 V, held over the step)",
        "u_y_v": "motor command Y, V (clipped to the DAC's +-10 V, held over the step)",
        "d_x_v": "input disturbance X, V (added at the motor, held over the step)",
        "d_y_v": "input disturbance Y, V (added at the motor, held over the step)",
    }
    outputs = dict(
        zip(
            (*MEASURED, *TRUE),
            (
                "encoder position X, m (0.5 um counts)",
                "encoder position Y, m (0.5 um counts)",
                "velocity X by backward difference of the encoder, m/s",
                "velocity Y by backward difference of the encoder, m/s",
                "true position X, m",
                "true position Y, m",
                "true velocity X, m/s",
                "true velocity Y, m/s",
            ),
            strict=True,
        )
    )
    return {"parameter_descriptions": params, "input_descriptions": inputs, "output_descriptions": outputs}


def export_plant(
    out: Path,
    model: PlantModel = "rig",
    payload_kg: float = 0.0,
    parameters: Mapping[str, float] | None = None,
) -> ExportedPlant:
    """Write the plant FMU of the shipped machine ``model`` to ``out`` (atomically: nothing half-written).

    payload_kg and ``parameters`` (by FMU parameter name: ``friction.x.fc_n``, ``start.x_m``, ...) set the
    parameters' defaults, which an importer may change before initialising. ValueError naming the parameter for a
    value out of its range or a name the machine has not; ``NotRegularFileError`` / OSError for ``out``.
    """
    plant = Plant.shipped(model, Payload(mass_kg=payload_kg))
    lugre = plant.friction.lugre
    values = default_parameters(plant)
    for name, value in (parameters or {}).items():
        if name not in values:
            raise ValueError(f"{name}: not a parameter of the {PLANT_WORDS[model]} plant; it has {', '.join(values)}")
        values[name] = float(value)
    build_plant(default_model_path(model), lugre, values)  # the defaults must start: refuse them now, not later
    version = package_version()
    label = f"{PLANT_WORDS[model]} plant (models/{PLANT_MODELS[model]})"
    settings = {
        "description": f"gantry-twin's {label} as a co-simulation FMU; {requirement(version)}",
        "gantry_twin_version": version,
        "plant": model,
        "model_file": f"models/{PLANT_MODELS[model]}",
        "lugre": lugre,
        "sample_period_s": plant.timestep_s,
        "parameters": values,
        **_descriptions(values),
    }
    with tempfile.TemporaryDirectory(prefix="gantry_plant_fmu_") as work:
        staging, built = Path(work) / "resources", Path(work) / "GantryPlant.fmu"
        (staging / "models").mkdir(parents=True)
        script = staging / Path(plant_slave.__file__).name
        shutil.copyfile(plant_slave.__file__, script)
        (staging / plant_slave.SETTINGS_FILE).write_text(json.dumps(settings, indent=1), encoding="utf-8")
        for name in MODEL_FILES[model]:
            shutil.copyfile(default_model_path(model).parent / name, staging / "models" / name)
        with _builder_path(staging):
            from pythonfmu.builder import FmuBuilder

            FmuBuilder.build_FMU(script, built, project_files=[staging / plant_slave.SETTINGS_FILE, staging / "models"])
        data = built.read_bytes()
    atomic_write(Path(out), lambda fh: fh.write(data))
    return ExportedPlant(Path(out), model, values, requirement(version), plant.timestep_s)


@contextlib.contextmanager
def _builder_path(staging: Path) -> Iterator[None]:
    """pythonfmu's builder imports the script by module name from its folder and leaves both behind: remove them,
    so that the FMU's own import (in this process) loads the FMU's copy."""
    module = Path(plant_slave.__file__).stem
    saved = list(sys.path)
    try:
        yield
    finally:
        sys.path[:] = saved
        sys.modules.pop(module, None)
