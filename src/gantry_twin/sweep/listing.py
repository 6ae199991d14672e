"""``gantry-twin sweeps``: the shipped sweeps, one line each (like ``gantry-twin scenarios``)."""

from __future__ import annotations

from pathlib import Path

from gantry_twin.sweep.spec import load_sweep, sweeps_dir


def shipped_sweeps() -> list[Path]:
    """Paths of the shipped sweep files, sorted by name."""
    return sorted(sweeps_dir().glob("*.yaml"))


def describe(path: Path) -> str:
    """One line about a sweep file: its ``description`` field, else the scenario it sweeps."""
    spec = load_sweep(path)
    return spec.description or f"a sweep of {spec.scenario}"


def listing() -> list[str]:
    """``<name>  <description>`` for every shipped sweep, names aligned."""
    paths = shipped_sweeps()
    width = max((len(p.stem) for p in paths), default=0)
    return [f"{p.stem:<{width}}  {describe(p)}" for p in paths]
