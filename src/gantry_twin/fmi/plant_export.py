"""Build the plant FMU: an FMI 2.0 co-simulation FMU of the rig or the paper's plant, native or with pythonfmu.

By default the FMU is native (:mod:`gantry_twin.fmi.plant_native`: C compiled at export against MuJoCo's
library, which goes into the FMU; it needs nothing but Linux x86-64 and its C library). ``python=True`` builds it
with pythonfmu: the FMU holds, in ``resources/``, :mod:`gantry_twin.fmi.plant_slave` (the ``Fmi2Slave``), its
settings (:data:`~gantry_twin.fmi.plant_slave.SETTINGS_FILE`: the machine, the parameters' defaults, the sample
period, the gantry-twin version) and the machine's MJCF files; pythonfmu's binary runs the slave in the Python
that loads the FMU, which needs gantry-twin installed (docs/fmi.md, "The plant as an FMU").
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
from gantry_twin.fmi.plant import build_plant, default_parameters, descriptions
from gantry_twin.fmi.plant_native import build_native
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


#: What the native FMU needs to run, in words.
NATIVE_REQUIREMENT = (
    "needs Linux x86-64 and its C library, nothing else: no Python, no MuJoCo installed "
    "(MuJoCo's library is inside, beside the FMU's own)"
)


def requirement(version: str, python: bool = True) -> str:
    """What the FMU needs to run, in words (the FMU's description and ``fmu export``'s output say it)."""
    if not python:
        return NATIVE_REQUIREMENT
    return (
        f"needs a Python (3.11 or later) with gantry-twin {version} installed, loaded in the importing process: "
        "pythonfmu's binary calls Python at every fmi2DoStep"
    )


def export_plant(
    out: Path,
    model: PlantModel = "rig",
    payload_kg: float = 0.0,
    parameters: Mapping[str, float] | None = None,
    python: bool = False,
) -> ExportedPlant:
    """Write the plant FMU of the shipped machine ``model`` to ``out`` (atomically: nothing half-written).

    payload_kg and ``parameters`` (by FMU parameter name: ``friction.x.fc_n``, ``start.x_m``, ...) set the
    parameters' defaults, which an importer may change before initialising. ValueError naming the parameter for a
    value out of its range or a name the machine has not; ``NotRegularFileError`` / OSError for ``out``.
    python: build with pythonfmu (needs gantry-twin where it runs) instead of the native FMU, which needs a C
    compiler here (:class:`~gantry_twin.fmi.plant_native.NoCompilerError` without one).
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
    description = f"gantry-twin's {label} as a co-simulation FMU; {requirement(version, python)}"
    if python:
        data = _pythonfmu_plant(model, plant, values, description, version)
    else:
        data = build_native(model, values, description, version, plant.timestep_s)
    atomic_write(Path(out), lambda fh: fh.write(data))
    return ExportedPlant(Path(out), model, values, requirement(version, python), plant.timestep_s)


def _pythonfmu_plant(
    model: PlantModel, plant: Plant, values: dict[str, float], description: str, version: str
) -> bytes:
    """The pythonfmu FMU's bytes."""
    settings = {
        "description": description,
        "gantry_twin_version": version,
        "plant": model,
        "model_file": f"models/{PLANT_MODELS[model]}",
        "lugre": plant.friction.lugre,
        "sample_period_s": plant.timestep_s,
        "parameters": values,
        **descriptions(values),
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
        return built.read_bytes()


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
