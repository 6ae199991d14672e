"""Scenario files: one typed schema, files that say only what differs, --set overrides.

A scenario is a YAML mapping validated into :class:`Scenario` (pydantic v2,
unknown keys rejected). Every field has a default (the paper's settings,
docs/equations.md), so ``{}`` is a valid scenario: DIARC on the paper's
circle, no load, no disturbance, quantised sensing, 30 s. The modules, in the order data flows:

* :mod:`.schema`: the fields. Domain settings (payload, sensing, plant
  changes, the built-in controllers' options) are validated by their own
  types, whose ranges are declared once (:mod:`gantry_twin.settings`).
* :mod:`.loading`: :func:`load_scenario` reads a file, applies ``--set
  key.path=value`` overrides and checks the cross-field rules (windows
  inside the duration).
* :mod:`.building`: :func:`build` turns a scenario into the objects
  :func:`gantry_twin.loop.simulate.simulate` takes, and checks what needs the
  compiled model (the contour inside the travel) and the controller.
* :mod:`.files`: the shipped scenarios; :mod:`.listing`: ``gantry-twin scenarios``.

Every problem is raised as :class:`ScenarioError`, whose message is one line
naming the file, the field path and what is allowed. docs/scenarios.md is the
reference of every field.
"""

from gantry_twin.scenario.building import BuiltRun, build, make_monitor, scenario_plant
from gantry_twin.scenario.errors import ScenarioError
from gantry_twin.scenario.files import display_source, resolve_scenario, scenarios_dir, shipped, shipped_scenarios
from gantry_twin.scenario.loading import (
    apply_overrides,
    controller_options,
    dump_yaml,
    load_scenario,
    parse_yaml,
    read_scenario_file,
    validate_data,
)
from gantry_twin.scenario.schema import Scenario

__all__ = [
    "BuiltRun",
    "Scenario",
    "ScenarioError",
    "apply_overrides",
    "build",
    "controller_options",
    "display_source",
    "dump_yaml",
    "load_scenario",
    "make_monitor",
    "scenario_plant",
    "parse_yaml",
    "read_scenario_file",
    "resolve_scenario",
    "scenarios_dir",
    "shipped",
    "shipped_scenarios",
    "validate_data",
]
