"""The plant FMU's Python side: pythonfmu's ``Fmi2Slave`` over :class:`gantry_twin.fmi.plant.CoSimPlant`.

:mod:`gantry_twin.fmi.plant_export` copies this file into the FMU's ``resources/`` beside
:data:`SETTINGS_FILE` (the machine, its parameters' defaults, the gantry-twin version it was exported from) and
the MJCF files; pythonfmu's binary imports it in the importing process's Python, which must have gantry-twin
installed (docs/fmi.md, "The plant as an FMU"). Only the FMI plumbing is here: variables, initialisation and
``do_step``; the plant and its samples are :mod:`gantry_twin.fmi.plant`'s.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any
from xml.etree.ElementTree import Element, SubElement

import numpy as np
from pythonfmu import DefaultExperiment, Fmi2Causality, Fmi2Slave, Fmi2Variability, Real
from pythonfmu.enums import Fmi2Status

try:
    from gantry_twin.fmi.plant import (
        INPUTS,
        OUTPUTS,
        START,
        CoSimPlant,
        build_plant,
        whole_samples,
    )
    from gantry_twin.run import package_version
except ImportError as exc:  # the FMU's Python has no (or a broken) gantry-twin
    raise ImportError(
        f"gantry-twin's plant FMU needs a Python with gantry-twin installed (the version its modelDescription.xml "
        f"names): {exc}"
    ) from None

#: The FMU's settings in resources/: written by the export, read when an instance is made.
SETTINGS_FILE = "gantry_plant.json"


def resources_path(resources: str) -> Path:
    """The resources folder pythonfmu passes (a path, or a ``file:`` URI from some importers)."""
    if resources.startswith("file:"):
        from urllib.parse import unquote, urlparse

        return Path(unquote(urlparse(resources).path))
    return Path(resources)


class GantryPlant(Fmi2Slave):
    """The gantry's plant: motor commands and disturbances in, the encoder and the true joint state out."""

    author = "gantry-twin"
    license = "MIT"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.resources_dir = resources_path(str(self.resources))
        settings = json.loads((self.resources_dir / SETTINGS_FILE).read_text(encoding="utf-8"))
        self.settings = settings
        self.description = settings["description"]
        self.version = settings["gantry_twin_version"]
        self.sample_period_s = float(settings["sample_period_s"])
        self.default_experiment = DefaultExperiment(0.0, None, self.sample_period_s)
        self.values: dict[str, float] = {name: float(v) for name, v in settings["parameters"].items()}
        self.values.update(dict.fromkeys((*INPUTS, *OUTPUTS), 0.0))
        for name, text in settings["parameter_descriptions"].items():
            self._variable(name, Fmi2Causality.parameter, Fmi2Variability.fixed, text)
        for name, text in settings["input_descriptions"].items():
            self._variable(name, Fmi2Causality.input, Fmi2Variability.continuous, text)
        for name, text in settings["output_descriptions"].items():
            self._variable(name, Fmi2Causality.output, Fmi2Variability.continuous, text)
        self.plant: CoSimPlant | None = None
        installed = package_version()
        if installed != self.version:
            self.log(
                f"exported from gantry-twin {self.version}, running on gantry-twin {installed}",
                Fmi2Status.warning,
            )

    def _variable(self, name: str, causality: Fmi2Causality, variability: Fmi2Variability, text: str) -> None:
        values = self.values

        def getter() -> float:
            return values[name]

        def setter(value: float) -> None:
            values[name] = float(value)

        setter = None if causality == Fmi2Causality.output else setter
        variable = Real(
            name, causality=causality, variability=variability, description=text, getter=getter, setter=setter
        )
        self.register_variable(variable, nested=False)

    def to_xml(self, model_options: dict[str, str] | None = None) -> Element:
        """pythonfmu's modelDescription.xml and its missing ``InitialUnknowns``: the outputs, computed at
        initialisation (from the start and friction parameters)."""
        root = super().to_xml(model_options or {})
        unknowns = SubElement(root.find("ModelStructure"), "InitialUnknowns")
        for index, variable in enumerate(self.vars.values(), 1):
            if variable.causality == Fmi2Causality.output:
                SubElement(unknowns, "Unknown", attrib={"index": str(index)})
        return root

    def exit_initialization_mode(self) -> None:
        """Build the plant with the parameters as set, start it and read the outputs at t = 0."""
        try:
            plant = build_plant(self.resources_dir / self.settings["model_file"], self.settings["lugre"], self.values)
        except ValueError as exc:
            message = str(exc).splitlines()[0]
            self.log(f"parameter {message}", Fmi2Status.error)
            raise ValueError(message) from None
        start = [self.values[name] for name in START]
        self.plant = CoSimPlant(plant, np.array(start[:2]), np.array(start[2:]))
        self.values.update(self.plant.outputs())

    def do_step(self, current_time: float, step_size: float) -> bool:
        """Hold the inputs over the step's samples; False (fmi2Error) with a logged line for a step that is not a
        whole multiple of the sample period, or a plant that cannot go on."""
        if self.plant is None:
            return self._error("doStep before the FMU was initialised (fmi2ExitInitializationMode)")
        samples = whole_samples(step_size, self.sample_period_s)
        if samples is None:
            return self._error(
                f"doStep at t = {current_time!r} s: communication step {step_size!r} s is not a whole multiple "
                f"of the plant's sample period {self.sample_period_s!r} s"
            )
        v = self.values
        u = np.array([v["u_x_v"], v["u_y_v"]])
        d = np.array([v["d_x_v"], v["d_y_v"]])
        problem = self.plant.advance(samples, u, d)
        v.update(self.plant.outputs())
        if problem is not None:
            return self._error(f"doStep at t = {current_time!r} s: {problem}")
        return True

    def _error(self, message: str) -> bool:
        """Log ``message`` with status fmi2Error and refuse the step: ``False``, which pythonfmu 0.7.0 returns as
        fmi2Discard (an exception would be fmi2Fatal, after which no call may reach the instance, not even
        fmi2FreeInstance)."""
        self.log(message, Fmi2Status.error)
        return False
