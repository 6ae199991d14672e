"""ScenarioError: one line naming the file, the field path and what is allowed."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NoReturn

from pydantic import ValidationError

from gantry_twin.scenario.files import display_source
from gantry_twin.scenario.schema import CONTOUR_TYPES, EVENT_TYPES
from gantry_twin.settings import best_errors, describe, loc_text, more, quote

_UNION_TAGS = {*CONTOUR_TYPES, *EVENT_TYPES}


class ScenarioError(ValueError):
    """A scenario that cannot run; ``str()`` is one line: file (a shipped one by name), field, what is allowed."""

    def __init__(self, source: str, field: str, message: str) -> None:
        self.source = source
        self.field = field
        self.message = message
        name = display_source(source)
        where = f"{name}: {field}: " if field else f"{name}: "
        super().__init__(where + message)


def raise_validation(exc: ValidationError, source: str, prefix: Sequence[Any] = ()) -> NoReturn:
    """The first of pydantic's errors as a ScenarioError (field path after ``prefix``), counting the others.

    The tags of the discriminated unions, which pydantic puts in the location
    after the union's field (``contour.circle.radius_m``), are dropped.
    """
    errors = best_errors(exc.errors())
    error = dict(errors[0])
    loc = [*prefix, *error["loc"]]
    error["loc"] = [p for i, p in enumerate(loc) if not (p in _UNION_TAGS and i and _is_union_field(loc[i - 1]))]
    ctx = error.get("ctx") or {}
    if error["type"] == "union_tag_invalid":
        allowed = ctx["expected_tags"]
        field, message = loc_text(error["loc"]) + ".type", f"unknown type {quote(ctx['tag'])}; allowed: {allowed}"
    elif error["type"] == "union_tag_not_found":  # only events have no default type
        field, message = loc_text(error["loc"]) + ".type", f"missing; allowed: {', '.join(EVENT_TYPES)}"
    else:
        field, message = describe(error)
    raise ScenarioError(source, field, message + more(errors)) from None


def _is_union_field(part: Any) -> bool:
    """The location part before a union's tag: the contour, or an item of a list of events."""
    return part == "contour" or isinstance(part, int)
