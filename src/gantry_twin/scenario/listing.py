"""``gantry-twin scenarios``: the shipped scenarios, one line each."""

from __future__ import annotations

from pathlib import Path

from gantry_twin.scenario.files import shipped_scenarios
from gantry_twin.scenario.loading import load_scenario


def describe(path: Path) -> str:
    """One line about a scenario file: its ``description`` field, else its contour and payload; its duration."""
    scenario = load_scenario(path)
    what = scenario.description or f"{scenario.contour.type}, payload {scenario.payload.mass_kg:g} kg"
    return f"{what} ({scenario.duration_s:g} s)"


def listing() -> list[str]:
    """``<name>  <description>`` for every shipped scenario, names aligned."""
    paths = shipped_scenarios()
    width = max((len(p.stem) for p in paths), default=0)
    return [f"{p.stem:<{width}}  {describe(p)}" for p in paths]
