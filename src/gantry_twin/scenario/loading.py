"""Loading a scenario: YAML -> mapping -> ``--set`` overrides -> :class:`Scenario` -> cross-field checks."""

from __future__ import annotations

import copy
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from gantry_twin.controllers import ArcGains
from gantry_twin.controllers.base import factory_for
from gantry_twin.ranges import fmt
from gantry_twin.scenario.errors import ScenarioError, raise_validation
from gantry_twin.scenario.schema import ControllerSpec, Scenario, typed_options


class _UniqueKeyLoader(yaml.SafeLoader):
    """safe_load that rejects a key given twice in one mapping."""


def _mapping_unique(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            mark = key_node.start_mark
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r} at line {mark.line + 1}, column {mark.column + 1}", mark
            )
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping_unique)


def parse_yaml(text: str, source: str) -> dict[str, Any]:
    """The top-level mapping of a scenario file (empty mapping not allowed)."""
    try:
        data = yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 -- a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ScenarioError(source, "", f"{where}YAML syntax error: {problem}") from None
    if data is None:
        raise ScenarioError(
            source, "", "empty file; expected a YAML mapping of scenario fields (write {} for all defaults)"
        )
    if not isinstance(data, dict):
        raise ScenarioError(
            source,
            "",
            f"top level must be a mapping of fields ({', '.join(Scenario.model_fields)}), got {type(data).__name__}",
        )
    return data


def read_scenario_file(path: str | Path) -> dict[str, Any]:
    """Read and parse a scenario file; missing or unreadable files are ScenarioErrors."""
    source = str(path)
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ScenarioError(source, "", "no such file; give a scenario YAML file") from None
    except IsADirectoryError:
        raise ScenarioError(source, "", "is a directory; give a scenario YAML file") from None
    except UnicodeDecodeError:
        raise ScenarioError(source, "", "not UTF-8 text; give a scenario YAML file") from None
    except OSError as exc:
        raise ScenarioError(source, "", f"cannot read ({exc.strerror})") from None
    return parse_yaml(text, source)


def apply_overrides(data: dict[str, Any], overrides: Iterable[str], source: str) -> dict[str, Any]:
    """Apply ``key.path=value`` overrides (value parsed as YAML) to a copy of data."""
    out = copy.deepcopy(data)
    for item in overrides:
        key, sep, text = item.partition("=")
        parts = key.strip().split(".")
        if not sep or not key.strip() or any(not p for p in parts):
            raise ScenarioError(source, "--set", f"{item!r}: expected key.path=value, e.g. payload.mass_kg=5")
        try:
            value = yaml.safe_load(text) if text.strip() else None
        except yaml.YAMLError as exc:
            raise ScenarioError(source, f"--set {key}", f"value {text!r} is not valid YAML ({exc.problem})") from None
        node: Any = out
        for depth, part in enumerate(parts[:-1]):
            here = ".".join(parts[: depth + 1])
            if isinstance(node, list):
                node = _list_item(node, part, source, here)
                continue
            if not isinstance(node, dict):
                raise ScenarioError(source, f"--set {key}", f"{here.rpartition('.')[0]} is not a mapping")
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            node = child
        last = parts[-1]
        if isinstance(node, list):
            index = _list_index(node, last, source, key)
            node[index] = value
        elif isinstance(node, dict):
            node[last] = value
        else:
            parent = ".".join(parts[:-1])
            raise ScenarioError(source, f"--set {key}", f"{parent} is a {type(node).__name__}, not a mapping")
    return out


def _list_index(node: list[Any], part: str, source: str, key: str) -> int:
    if not part.isdigit() or int(part) >= len(node):
        raise ScenarioError(source, f"--set {key}", f"index {part!r} not in 0..{len(node) - 1}")
    return int(part)


def _list_item(node: list[Any], part: str, source: str, key: str) -> Any:
    return node[_list_index(node, part, source, key)]


def validate_data(data: dict[str, Any], source: str, default_name: str | None = None) -> Scenario:
    """Validate a parsed mapping into a Scenario and check the cross-field rules."""
    try:
        scenario = Scenario.model_validate(data)
    except ValidationError as exc:
        raise_validation(exc, source)
    if scenario.name is None and default_name is not None:
        scenario = scenario.model_copy(update={"name": default_name})
    controller_options(scenario, source)
    _check_windows(scenario, source)
    _check_monitor(scenario, source)
    return scenario


def _check_monitor(scenario: Scenario, source: str) -> None:
    m, d = scenario.monitor, scenario.duration_s
    if m.enable and m.baseline_summary is None and m.baseline_window_s[1] > d + 1e-9:
        a, b = m.baseline_window_s
        raise ScenarioError(
            source,
            "monitor.baseline_window_s",
            f"must lie inside [0, duration_s = {fmt(d)}] s, got [{fmt(a)}, {fmt(b)}] s "
            "(or give monitor.baseline_summary)",
        )


def _check_windows(scenario: Scenario, source: str) -> None:
    d = scenario.duration_s
    for field, given, window, what in (
        ("window_s", scenario.window_s, scenario.metric_window_s, "the second period [T, 2T]"),
        ("estimates_window_s", scenario.estimates_window_s, scenario.estimate_window_s, "the last period"),
    ):
        lo, hi = window  # end > start: a given window by its type (ranges.Window), a default by construction
        if lo < 0.0 or hi > d + 1e-9:
            if given is None:
                raise ScenarioError(
                    source,
                    field,
                    f"the default, {what} = [{lo:.4g}, {hi:.4g}] s, lies outside duration_s = "
                    f"{fmt(d)} s; set {field} inside [0, {fmt(d)}] s or lengthen duration_s",
                )
            raise ScenarioError(
                source, field, f"must lie inside [0, duration_s = {fmt(d)}] s, got [{fmt(lo)}, {fmt(hi)}] s"
            )


def load_scenario(path: str | Path, overrides: Sequence[str] = (), controller: str | None = None) -> Scenario:
    """Read, override and validate a scenario file.

    ``controller`` (the command line's ``--controller``) replaces
    ``controller.name``; if it differs from the file's, the file's
    controller options are dropped (they belong to the other controller).
    ``overrides`` (``--set``) apply after that.
    """
    source = str(path)
    data = read_scenario_file(path)
    if controller is not None:
        current = data.get("controller")
        current = current if isinstance(current, dict) else {}
        if current.get("name", ControllerSpec().name) != controller:
            current = {}
        data["controller"] = {**current, "name": controller}
    data = apply_overrides(data, overrides, source)
    return validate_data(data, source, default_name=Path(path).stem)


def controller_options(scenario: Scenario, source: str = "<scenario>") -> dict[str, Any]:
    """Keyword arguments of the controller's factory: validated for a built-in, as given for a plug-in.

    A scenario also requires that any ``gains`` start theta^ inside its
    bounds (:meth:`ArcGains.theta0_in_bounds`).
    """
    given = scenario.controller.options
    options = typed_options(factory_for(scenario.controller.name))
    if options is None:
        return dict(given)
    try:
        typed = options.model_validate(given)
    except ValidationError as exc:
        raise_validation(exc, source, ("controller", "options"))
    kwargs = {name: getattr(typed, name) for name in given}
    for name, value in kwargs.items():
        if isinstance(value, ArcGains) and not value.theta0_in_bounds():
            raise ScenarioError(
                source, f"controller.options.{name}", "need theta_min <= theta0 <= theta_max element-wise"
            )
    return kwargs


def dump_yaml(data: dict[str, Any]) -> str:
    """Stable YAML text (key order kept, block style)."""
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, allow_unicode=True)
