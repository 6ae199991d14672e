"""docs/scenarios.md's table of every field against the schema: the committed table is the generated one, every
field a scenario holds is in it with its default, and each range it states is the one validation enforces."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from gantry_twin.controllers.base import factory_for
from gantry_twin.scenario import ScenarioError, validate_data
from gantry_twin.scenario.reference import BEGIN, END, field_rows, field_table
from gantry_twin.scenario.schema import Scenario, typed_options

DOC = Path(__file__).resolve().parents[1] / "docs" / "scenarios.md"
#: "[lo, hi] unit" or "(lo, hi] unit" with a finite upper end.
INTERVAL = re.compile(r"^([\[(])(-?[\d.e+]+|-inf), (-?[\d.e+]+)\]( [^,]+)?$")


def committed_table() -> str:
    text = DOC.read_text(encoding="utf-8")
    return text[text.index(BEGIN) : text.index(END) + len(END)] + "\n"


def test_the_committed_table_is_the_generated_one():
    assert committed_table() == field_table(), "docs/scenarios.md is stale: run python tools/scenario_reference.py"


def _leaves(data, prefix=""):
    """(dotted path, value) of every leaf of a dumped model (lists and empty mappings are leaves)."""
    if isinstance(data, dict) and data:
        for key, value in data.items():
            yield from _leaves(value, f"{prefix}{key}.")
    else:
        yield prefix.rstrip("."), data


def _cell(value) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(_cell(v) for v in value) + "]"
    if isinstance(value, bool) or value is None:
        return "true" if value is True else "false" if value is False else "null"
    if isinstance(value, float):
        return f"{value:g}"
    return f'"{value}"' if isinstance(value, str) else str(value)


@pytest.mark.parametrize(
    ("data", "skip"),
    [
        ({}, ()),  # the default scenario: circle, no friction model given
        ({"contour": {"type": "ellipse"}}, ()),
        ({"plant": {"friction": {"model": "lugre"}, "offset": {}, "ripple": {}}}, ()),
        ({"changes": {"velocity_noise": {"std_m_s": [0, 0]}}}, ()),
    ],
)
def test_every_field_a_scenario_holds_is_documented_with_its_default(data, skip):
    """Every leaf of a scenario (sections that are null by default given, to reach their fields) is a row
    whose default is the value the schema fills in (the values given here apart)."""
    skip = {*skip, *(path for path, _ in _leaves(data))}
    documented = {}
    for path, default, _ in field_rows():
        documented.setdefault(path, set()).add(default)
    dumped = Scenario.model_validate(data).model_dump(mode="json")
    for path, value in _leaves(dumped):
        if path.endswith(".type") or path == "type" or path in skip:
            continue
        assert path in documented, f"{path} is not in docs/scenarios.md"
        assert f"`{_cell(value)}`" in documented[path], (path, value, documented[path])


@pytest.mark.parametrize("name", ["darc", "diarc", "drc", "pd"])
def test_every_option_of_a_built_in_controller_is_documented(name):
    options = typed_options(factory_for(name))
    rows = field_rows()
    start = rows.index((f"controller.options (name: {name})", "", ""))
    own = []
    for path, default, allowed in rows[start + 1 :]:
        if not (default or allowed):
            break
        own.append(path)
    for field in options.model_fields:
        assert f"controller.options.{field}" in own, (name, field)
    if name == "diarc":  # the two fields the recommended estimator sets
        assert "controller.options.estimator.friction_slope_s_m" in own
        assert "controller.options.estimator.reversal_gate" in own


def _scalar_rows():
    """(heading's data, path, allowed) of every scalar field with a finite interval, outside lists."""
    base: dict = {}
    prefix = ""
    for path, default, allowed in field_rows():
        if prefix and not path.startswith(prefix + "."):  # past the rows of a heading
            base, prefix = {}, ""
        if not (default or allowed):
            heading = path
            prefix = heading.split(" ")[0]
            if "(type: " in heading and "[i]" not in heading:
                base = {"contour": {"type": heading.split("type: ")[1].rstrip(")")}}
            elif "(name: " in heading:
                base = {"controller": {"name": heading.split("name: ")[1].rstrip(")")}}
            else:
                base = {"skip": True}
            continue
        if (
            "skip" in base
            or "[i]" in path
            or "gcode" in str(base)
            or not INTERVAL.match(allowed.removesuffix(", or null"))
        ):
            continue
        yield base, path, allowed.removesuffix(", or null")


def _set(data: dict, path: str, value) -> dict:
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}
    node = out
    parts = path.split(".")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
    node[parts[-1]] = value
    return out


@pytest.mark.parametrize(
    ("base", "path", "allowed"), list(_scalar_rows()), ids=lambda v: v if isinstance(v, str) else ""
)
def test_each_documented_range_is_the_one_validation_enforces(base, path, allowed):
    hi = float(INTERVAL.match(allowed).group(3))
    data = _set(base, path, hi * 2 + 1)  # above the documented upper end
    if path.startswith("plant.friction.") and path.count(".") == 3:
        data = _set(data, "plant.friction.model", "lugre")
    if path.startswith("changes.velocity_noise."):  # its one required field
        data = _set(data, "changes.velocity_noise.std_m_s", [0.0, 0.0])
    with pytest.raises(ScenarioError) as caught:
        validate_data(data, "s.yaml")
    assert f"must be in {allowed}" in str(caught.value) or f"must be {allowed}" in str(caught.value), caught.value
    assert path.rsplit(".", 1)[-1] in str(caught.value)
