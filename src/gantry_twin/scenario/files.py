"""The shipped scenario files (``scenarios/*.yaml``)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def scenarios_dir() -> Path:
    """The shipped scenarios: ``gantry_twin/scenarios`` in a wheel, ``scenarios/`` in a checkout."""
    package = Path(str(resources.files("gantry_twin")))
    packaged = package / "scenarios"
    return packaged if packaged.is_dir() else package.parents[1] / "scenarios"


def shipped_scenarios() -> list[Path]:
    """Paths of the shipped scenario files, sorted by name."""
    return sorted(scenarios_dir().glob("*.yaml"))


def shipped(name: str) -> Path:
    """The shipped scenario called ``name`` (with or without ``.yaml``)."""
    return scenarios_dir() / (name if name.endswith(".yaml") else f"{name}.yaml")
