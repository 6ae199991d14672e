"""Loading a scenario: YAML -> mapping -> ``--set`` overrides -> :class:`Scenario` -> cross-field checks."""

from __future__ import annotations

import copy
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from gantry_twin.controllers import ArcGains, PluginError
from gantry_twin.controllers.base import factory_for
from gantry_twin.inputs import InputFileError, read_input_file
from gantry_twin.scenario.errors import ScenarioError, raise_validation
from gantry_twin.scenario.schema import ControllerSpec, Scenario, typed_options
from gantry_twin.settings import QUOTE_MAX_CHARS, fmt, label_from, quote, shorten

#: Deepest nesting of mappings and lists in a YAML input (a scenario needs 5; ``--set`` paths alike).
INPUT_MAX_DEPTH = 20

_YAML_BASE: type = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml's parser when present (faster)


class _Loader(_YAML_BASE):  # type: ignore[misc, valid-type]
    """safe_load that rejects a key given twice in one mapping and an integer too long to convert."""


def _mapping_unique(loader: _Loader, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            mark = key_node.start_mark
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {quote(key)} at line {mark.line + 1}, column {mark.column + 1}", mark
            )
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


def _integer(loader: _Loader, node: yaml.ScalarNode) -> int:
    try:
        return yaml.constructor.SafeConstructor.construct_yaml_int(loader, node)
    except ValueError:  # more digits than int() converts (sys.get_int_max_str_digits)
        raise yaml.constructor.ConstructorError(
            None, None, f"integer of {len(node.value)} characters is too long", node.start_mark
        ) from None


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping_unique)
_Loader.add_constructor("tag:yaml.org,2002:int", _integer)
# YAML 1.1 (PyYAML) reads 1e-3 or 5e7, without a decimal point, as a string; YAML 1.2 and every user read a number.
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def _check_events(text: str) -> None:
    """Refuse aliases (no expansion, no alias bomb) and nesting deeper than INPUT_MAX_DEPTH, before composing."""
    depth = 0
    for event in yaml.parse(text, Loader=_YAML_BASE):
        if isinstance(event, yaml.AliasEvent):
            raise yaml.MarkedYAMLError(
                problem=f"alias *{shorten(str(event.anchor))} refused: write the value out "
                "(YAML anchors and aliases are not supported)",
                problem_mark=event.start_mark,
            )
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
            if depth > INPUT_MAX_DEPTH:
                raise yaml.MarkedYAMLError(
                    problem=f"nested deeper than {INPUT_MAX_DEPTH} levels", problem_mark=event.start_mark
                )
        elif isinstance(event, yaml.CollectionEndEvent):
            depth -= 1


def load_yaml(text: str) -> Any:
    """Parse bounded YAML text (see :func:`_check_events`); yaml.YAMLError on any problem."""
    _check_events(text)
    return yaml.load(text, Loader=_Loader)  # noqa: S506 -- a SafeLoader (or CSafeLoader) subclass


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """``line L, column C: YAML syntax error: problem`` (the problem cut short)."""
    mark = getattr(exc, "problem_mark", None)
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    return f"{where}YAML syntax error: {shorten(problem, 3 * QUOTE_MAX_CHARS)}"


def parse_yaml(text: str, source: str) -> dict[str, Any]:
    """The top-level mapping of a scenario file (empty mapping not allowed)."""
    try:
        data = load_yaml(text)
    except yaml.YAMLError as exc:
        raise ScenarioError(source, "", _yaml_problem(exc)) from None
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
    """Read and parse a scenario file (:func:`read_input_file`); any problem is a ScenarioError."""
    try:
        text = read_input_file(path, "a scenario YAML file")
    except InputFileError as exc:
        raise ScenarioError(str(path), "", str(exc)) from None
    return parse_yaml(text, str(path))


def apply_overrides(data: dict[str, Any], overrides: Iterable[str], source: str) -> dict[str, Any]:
    """Apply ``key.path=value`` overrides (value parsed as YAML) to a copy of data.

    A missing mapping on the path is created; a list item is addressed by
    its index, which must exist.
    """
    out = copy.deepcopy(data)
    for item in overrides:
        key, sep, text = item.partition("=")
        parts = key.strip().split(".")
        if not sep or not key.strip() or any(not p for p in parts):
            raise ScenarioError(source, "--set", f"{quote(item)}: expected key.path=value, e.g. payload.mass_kg=5")
        field = f"--set {shorten(key.strip())}"
        if len(parts) > INPUT_MAX_DEPTH:
            raise ScenarioError(source, field, f"a path of more than {INPUT_MAX_DEPTH} parts")
        try:
            value = load_yaml(text) if text.strip() else None
        except yaml.YAMLError as exc:
            why = _yaml_problem(exc).partition("YAML syntax error: ")[2]
            raise ScenarioError(source, field, f"value {quote(text)} is not valid YAML ({why})") from None
        node: Any = out
        for depth, part in enumerate(parts):
            here = shorten(".".join(parts[:depth]))
            last = depth == len(parts) - 1
            if isinstance(node, list):
                index = _list_index(node, part, here)
                if index is None:
                    raise ScenarioError(source, field, f"index {quote(part)} is out of range: {_items(node, here)}")
                if last:
                    node[index] = value
                node = node[index]
            elif isinstance(node, dict):
                if last:
                    node[part] = value
                elif node.get(part) is None:
                    if _is_index(parts[depth + 1]):  # an index into a list that is not there
                        what = shorten(".".join(parts[: depth + 1]))
                        raise ScenarioError(
                            source, field, f"index {quote(parts[depth + 1])} is out of range: {what} has no items"
                        )
                    node[part] = {}
                node = node[part]
            else:
                raise ScenarioError(source, field, f"{here} is {quote(node)}, not a mapping")
    return out


def _is_index(part: str) -> bool:
    return part.isascii() and part.isdigit()


def _list_index(node: list[Any], part: str, here: str) -> int | None:
    """The index ``part`` names in ``node``, or None if it names none."""
    if _is_index(part) and len(part) <= 9 and int(part) < len(node):
        return int(part)
    return None


def _items(node: list[Any], here: str) -> str:
    """``<here> has N items (0..N-1)`` / ``has no items``."""
    n = len(node)
    return f"{here} has no items" if n == 0 else f"{here} has {n} item{'s' if n > 1 else ''} (index 0..{n - 1})"


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
        lo, hi = window  # end > start: a given window by its type (settings.Window), a default by construction
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
    return validate_data(data, source, default_name=label_from(Path(path).stem))


def controller_options(scenario: Scenario, source: str = "<scenario>") -> dict[str, Any]:
    """Keyword arguments of the controller's factory: validated for a built-in, as given for a plug-in.

    A scenario also requires that any ``gains`` start theta^ inside its
    bounds (:meth:`ArcGains.theta0_in_bounds`).
    """
    given = scenario.controller.options
    try:
        options = typed_options(factory_for(scenario.controller.name))
    except PluginError as exc:  # its module is missing or raises at import (made, it is building's to report)
        raise ScenarioError(source, "controller.name", shorten(str(exc), 200)) from None
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
