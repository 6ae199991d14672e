"""The shipped scenario files (``scenarios/*.yaml``): where they are, their names, a scenario argument resolved."""

from __future__ import annotations

import difflib
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


def shipped_names() -> list[str]:
    """The names of the shipped scenarios (``no_load_circle``), sorted."""
    return [p.stem for p in shipped_scenarios()]


def display_source(source: str | Path) -> str:
    """How messages name a scenario file: a shipped one by its name (``no_load_circle``), any other by its path."""
    path = Path(source)
    if path.suffix == ".yaml" and path.stem in shipped_names():
        try:
            if path.resolve() == shipped(path.stem).resolve():
                return path.stem
        except OSError:
            pass
    return str(source)


def resolve_scenario(arg: str) -> Path:
    """A file path, or the shipped scenario called ``arg`` when no such file exists.

    FileNotFoundError (one line) for a bare name that is neither, with the
    nearest shipped name if one is close (``no_load_circl``).
    """
    path = Path(arg)
    if path.exists() or path.is_symlink() or "/" in arg:  # a file (a broken link too: reading it says why)
        return path
    if shipped(arg).is_file():
        return shipped(arg)
    names = shipped_names()
    close = difflib.get_close_matches(path.name.removesuffix(".yaml"), names, n=1)
    hint = f"did you mean '{close[0]}'?" if close else f"shipped: {', '.join(names)}"
    raise FileNotFoundError(f"no such scenario file or shipped scenario '{arg}'; {hint}")
