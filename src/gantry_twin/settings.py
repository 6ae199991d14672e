"""Settings validated where they are declared: each range once, as the type of its field.

Every setting of the twin (the payload, the sensor, a plant change, the
controllers' gains and estimator, the monitor) is a frozen dataclass made
by :func:`validated`, whose fields carry their allowed range in their type::

    @validated("payload")
    class Payload:
        mass_kg: Range(0.0, PAYLOAD_MAX_KG, "kg") = 0.0

That one declaration checks a value given from Python (``Payload(-1)``
raises the one-line ValueError ``payload.mass_kg: must be in [0, 20] kg, got
-1.0``) and the same field in a scenario file (pydantic validates the
dataclass as a field of the scenario; :mod:`gantry_twin.scenario` reports the
file and the field path). Rules between fields raise :func:`rule` from the
dataclass' ``__post_init__``. Settings are read when a run is built, never
per sample.

:func:`describe` turns one pydantic error into (field path, message); both
the Python errors and the scenario errors use it.
"""

from __future__ import annotations

import functools
import math
import numbers
import re
import reprlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import Annotated, Any, TypeVar, dataclass_transform

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    TypeAdapter,
    ValidationError,
    model_validator,
)
from pydantic.dataclasses import dataclass as pydantic_dataclass
from pydantic_core import PydanticCustomError

#: Highest frequency a setting may name, Hz: half the 5 kHz sample rate (Ts = 0.2 ms).
FREQUENCY_MAX_HZ = 2500.0
#: Largest volts a setting may name: the DS1103's DAC range is +-10 V (the
#: ctrlrange of models/gantry.xml, which the loop applies).
VOLTS_MAX_V = 10.0

_WORDS = {1: "one", 2: "two", 3: "three", 4: "four", 6: "six", 8: "eight"}

#: Longest piece of a given value (or of the text around it) that an error message echoes, characters.
QUOTE_MAX_CHARS = 40


def _bounded_repr() -> reprlib.Repr:
    """A repr that stops early in big or deep values: its work is bounded, not just its length."""
    r = reprlib.Repr()
    r.maxlevel, r.maxstring, r.maxlong, r.maxother = 2, QUOTE_MAX_CHARS + 2, QUOTE_MAX_CHARS, QUOTE_MAX_CHARS
    r.maxlist = r.maxtuple = r.maxdict = r.maxset = r.maxfrozenset = r.maxdeque = r.maxarray = 4
    return r


_REPR = _bounded_repr()


def shorten(text: str, limit: int = QUOTE_MAX_CHARS) -> str:
    """``text`` cut to its first ``limit`` characters (``...`` marks the cut)."""
    return text if len(text) <= limit else text[: max(limit - 3, 1)] + "..."


def quote(value: Any) -> str:
    """A given value as an error message echoes it: its repr, cut to a short prefix (:func:`shorten`).

    Every message that shows what the user gave goes through here, so that
    no input (a 50 MB string, a deeply nested list) makes a long message or a
    long wait: the repr itself stops early (``reprlib``).
    """
    if isinstance(value, str):
        return shorten(repr(value[: QUOTE_MAX_CHARS + 1]))
    try:
        return shorten(_REPR.repr(value))
    except Exception:  # a plug-in's object whose __repr__ fails  # noqa: BLE001
        return f"<{type(value).__name__}>"


def fmt(x: float | None, none: str = "inf") -> str:
    """A bound as the errors print it: 20.0 -> 20, 1e-3 -> 0.001."""
    return none if x is None else f"{x:g}"


def signed_pct(x: float | None, decimals: int = 1, width: int = 0, unit: str = " %", none: str = "-") -> str:
    """A signed percentage as every report and summary prints it: ``+1.2 %``, ``-0.4 %``; a value that rounds
    to zero is ``0.0 %``, never ``-0.0 %`` (nor ``+0.0 %``); ``none`` for None or NaN. ``width`` pads the
    number (not the unit) on the left, for columns."""
    if x is None or x != x:
        return f"{none:>{width}}"
    text = f"{x:+.{decimals}f}"
    if float(text) == 0.0:
        text = f"{0.0:.{decimals}f}"
    return f"{text:>{width}}{unit}"


def interval(lo: float | None, hi: float | None, unit: str = "", lo_open: bool = False) -> str:
    """``[lo, hi] unit`` (``(lo, hi]`` when lo_open); None is unbounded."""
    left = "(" if lo_open else "["
    return f"{left}{fmt(lo, '-inf')}, {fmt(hi)}] {unit}".rstrip()


# ---------------------------------------------------------------------------
# Field types.


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _type_error(value: Any, kind: str, allowed: str = "", article: str = "a") -> PydanticCustomError:
    """A ``kind`` (e.g. "number") in ``allowed`` was expected, and ``value`` is none."""
    where = f" in {allowed}" if allowed else ""
    if isinstance(value, bool):
        return PydanticCustomError(
            "range",
            "must be {kind}, not a boolean{where}",
            {"kind": f"{article} {kind}", "where": f"; allowed: {allowed}" if allowed else ""},
        )
    return PydanticCustomError(
        "range", "must be a valid {kind}{where}, got {value}", {"kind": kind, "where": where, "value": quote(value)}
    )


@dataclass(frozen=True)
class Allowed:
    """What a field type allows, in the words of its errors: carried in the type's ``Annotated`` metadata for the
    generated scenario reference (:mod:`gantry_twin.scenario.reference`); pydantic ignores it."""

    text: str
    #: A :func:`Range`'s bounds (None: unbounded or not a range), for code that checks the range elsewhere (the
    #: native plant FMU's C, :mod:`gantry_twin.fmi.plant_native`).
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False


def Range(lo: float | None, hi: float | None, unit: str = "", *, lo_open: bool = False) -> Any:  # noqa: N802
    """A finite float in [lo, hi] (``(lo, hi]`` with lo_open; None: unbounded) whose error states the range."""
    allowed = interval(lo, hi, unit, lo_open)

    def check(value: Any) -> float:
        if not _is_number(value):
            raise _type_error(value, "number", allowed)
        x = _as_float(value)
        bad = not math.isfinite(x)
        bad |= lo is not None and (x <= lo if lo_open else x < lo)
        bad |= hi is not None and x > hi
        if bad:
            raise PydanticCustomError(
                "range",
                "must be in {allowed}, got {value}",
                {"allowed": allowed, "value": quote(x if math.isfinite(x) or isinstance(value, float) else value)},
            )
        return x

    return Annotated[float, BeforeValidator(check), Allowed(allowed, lo, hi, lo_open)]


def _as_float(value: Any) -> float:
    """float(value); an integer too large for a float (YAML ``0xfff...``) is infinite, not an OverflowError."""
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def Count(lo: int, hi: int) -> Any:  # noqa: N802
    """An integer in [lo, hi] (a float with an integral value is accepted)."""

    def check(value: Any) -> int:
        whole = isinstance(value, numbers.Integral) or (_is_number(value) and float(value).is_integer())
        if isinstance(value, bool) or not whole:
            raise _type_error(value, "integer", f"[{lo}, {hi}]", "an")
        if not lo <= int(value) <= hi:
            raise PydanticCustomError(
                "range", "must be an integer in [{lo}, {hi}], got {value}", {"lo": lo, "hi": hi, "value": quote(value)}
            )
        return int(value)

    return Annotated[int, BeforeValidator(check), Allowed(f"an integer in [{lo}, {hi}]")]


def Vector(component: Any, names: Sequence[str]) -> Any:  # noqa: N802
    """A tuple of len(names) values of type ``component`` (e.g. ``Vector(Positive, AXES)``).

    component: one type for all, or a tuple of one type per component.
    Errors name the component: ``[i]`` in a scenario file, ``.name`` from Python.
    """
    names = tuple(names)
    per_item = component if isinstance(component, tuple) else (component,) * len(names)
    adapters = [TypeAdapter(c) for c in per_item]
    count = f"{_WORDS.get(len(names), len(names))} numbers ({', '.join(names)})"

    def check(value: Any) -> tuple[Any, ...]:
        if isinstance(value, str | bytes | dict) or not hasattr(value, "__len__") or not hasattr(value, "__iter__"):
            raise PydanticCustomError("range", "must be {count}, got {value}", {"count": count, "value": quote(value)})
        if len(value) != len(names):
            few = "too few items" if len(value) < len(names) else "too many items"
            raise PydanticCustomError(
                "range", "{few}: must be {count}, got {n}", {"few": few, "count": count, "n": len(value)}
            )
        out = []
        for i, x in enumerate(value):
            try:
                out.append(adapters[i].validate_python(x))
            except ValidationError as exc:
                error = exc.errors()[0]
                raise PydanticCustomError(
                    error["type"], "{message}", {"message": error["msg"], "component": i, "name": names[i]}
                ) from None
        return tuple(out)

    each = sorted({allowed_text(c) for c in per_item})
    text = f"{count}" + (f", each in {each[0]}" if len(each) == 1 and each[0] else "")
    if len(each) > 1:
        text += ": " + ", ".join(f"{n} in {allowed_text(c)}" for n, c in zip(names, per_item, strict=True))
    return Annotated[tuple[Any, ...], BeforeValidator(check), Allowed(text)]


def allowed_text(kind: Any) -> str:
    """The :class:`Allowed` text of a field type, or empty."""
    for meta in reversed(getattr(kind, "__metadata__", ())):
        if isinstance(meta, Allowed):
            return meta.text
    return ""


def OrNamed(kind: Any, choices: dict[str, Any]) -> Any:  # noqa: N802
    """``kind``, or in a scenario file the name of one of ``choices`` (e.g. ``estimator: recommended``)."""
    allowed = " or ".join(repr(name) for name in choices) + ", or a mapping of its fields"

    def by_name(value: Any) -> Any:
        if isinstance(value, dict | kind):
            return value
        if not isinstance(value, str) or value not in choices:
            raise PydanticCustomError("literal_error", "Input should be {allowed}", {"allowed": allowed})
        return choices[value]

    return Annotated[kind, BeforeValidator(by_name), Allowed(allowed)]


def _ordered(window: tuple[float, float]) -> tuple[float, float]:
    a, b = window
    if b <= a:
        raise PydanticCustomError("range", "end must be after start, got [{a}, {b}] s", {"a": fmt(a), "b": fmt(b)})
    return window


def _any_number(value: Any) -> float:
    if not _is_number(value):
        raise _type_error(value, "number")
    return _as_float(value)


#: Any number (not a boolean), NaN and infinities included.
Number = Annotated[float, BeforeValidator(_any_number)]
Real = Range(None, None)
Positive = Range(0.0, None, lo_open=True)
NonNegative = Range(0.0, None)
Seconds = Range(0.0, None, "s")
#: A time window [start, end], s, end after start.
Window = Annotated[
    Vector(Seconds, ("start", "end")), AfterValidator(_ordered), Allowed("[start, end] s, start >= 0, end > start")
]
#: A frequency of the sampled system, Hz.
Frequency = Range(0.0, FREQUENCY_MAX_HZ, "Hz", lo_open=True)

#: Longest label, characters.
LABEL_MAX_CHARS = 64
#: The characters of a label, in words (the error and docs/scenarios.md say them).
LABEL_RULE = f"1 to {LABEL_MAX_CHARS} letters A-Z a-z, digits, '_', '-' or '.', starting with a letter, digit or '_'"
_LABEL = re.compile(rf"[A-Za-z0-9_][A-Za-z0-9_.-]{{0,{LABEL_MAX_CHARS - 1}}}")


def _label(value: Any) -> str:
    if not isinstance(value, str):
        raise _type_error(value, "string")
    if not _LABEL.fullmatch(value):
        raise PydanticCustomError(
            "range",
            "must be a label, not a path: {rule}; got {value}",
            {"rule": LABEL_RULE, "value": quote(value)},
        )
    return value


#: A name that becomes one directory name (``runs/<name>/``): never a path (no '/', '..', leading '.' or '-').
Label = Annotated[str, BeforeValidator(_label), Allowed(f"a label: {LABEL_RULE}")]


def label_from(text: str) -> str:
    """The nearest :data:`Label` to ``text`` (a file's stem): other characters become '_', cut to length."""
    cleaned = re.sub(r"[^A-Za-z0-9_.-]", "_", text)
    if cleaned[:1] in ("", ".", "-"):
        cleaned = "_" + cleaned
    return cleaned[:LABEL_MAX_CHARS]


def rule(field: str, message: str) -> PydanticCustomError:
    """A broken rule between fields, raised from ``__post_init__``; ``field`` is the one it names."""
    return PydanticCustomError("rule", "{message}", {"message": message, "field": field})


# ---------------------------------------------------------------------------
# Settings dataclasses.

T = TypeVar("T")


def known_keys(cls: type, data: Any) -> Any:
    """Unknown keys of a mapping are an error that lists the allowed keys."""
    if isinstance(data, dict):
        allowed = (
            [f.name for f in fields(cls) if f.init] if hasattr(cls, "__dataclass_fields__") else list(cls.model_fields)
        )
        for key in data:
            if key not in allowed:
                raise PydanticCustomError(
                    "unknown_key",
                    "unknown key '{key}'; allowed: {allowed}",
                    {"key": shorten(str(key)), "allowed": ", ".join(allowed)},
                )
    return data


@dataclass_transform(frozen_default=True)
class Model(BaseModel):
    """The one pydantic base of the package's files (a scenario, a sweep spec, summary.json): frozen, unknown keys
    rejected with the list of allowed keys."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    _known_keys = model_validator(mode="before")(classmethod(known_keys))


def validated(name: str) -> Callable[[type[T]], type[T]]:
    """Make ``cls`` a frozen, validated dataclass; ``name`` prefixes the field in its errors from Python.

    Unknown keys are rejected. From Python a bad value is a one-line
    ValueError ``name.field: what is allowed, got what``; inside a pydantic
    model (a scenario) the usual ValidationError, at the field's path.
    """

    def make(cls: type[T]) -> type[T]:
        cls._known_keys = model_validator(mode="before")(classmethod(known_keys))  # type: ignore[attr-defined]
        made = pydantic_dataclass(frozen=True, config=ConfigDict(extra="forbid"))(cls)
        init = made.__init__

        @functools.wraps(init)
        def __init__(self: Any, *args: Any, **kwargs: Any) -> None:  # noqa: N807
            try:
                init(self, *args, **kwargs)
            except ValidationError as exc:
                raise ValueError(python_message(exc, made, name)) from None

        made.__init__ = __init__  # type: ignore[method-assign]
        return made

    return make


def python_message(exc: ValidationError, cls: type, name: str) -> str:
    """One line for a settings object built from Python: ``name.field: message``."""
    errors = best_errors(exc.errors())
    error = dict(errors[0])
    loc = list(error["loc"])
    init_fields = [f.name for f in fields(cls) if f.init]
    if loc and isinstance(loc[0], int) and loc[0] < len(init_fields):
        loc[0] = init_fields[loc[0]]  # a positional argument
    error["loc"] = tuple(loc)
    path, message = describe(error, component_names=True, allowed=init_fields)
    return join(name, path) + ": " + message + more(errors)


# ---------------------------------------------------------------------------
# Error text.

_MISMATCH = {"literal_error", "string_type", "model_type", "dict_type", "model_attributes_type", "dataclass_type"}
#: Errors whose message already says what was given.
_SAYS_GIVEN = {"range", "rule", "order", "unknown_key", "unknown_controller"}


def best_errors(errors: list[Any]) -> list[Any]:
    """Drop a union's "wrong branch" errors when another branch says what is really wrong."""
    real = [e for e in errors if e["type"] not in _MISMATCH]
    return real or errors


def more(errors: list[Any]) -> str:
    """`` (and N more problems)`` when there are other errors than the first."""
    n = len(errors) - 1
    return f" (and {n} more problem{'s' if n > 1 else ''})" if n else ""


def join(*parts: str) -> str:
    """Field path parts joined with dots (``a`` + ``[1]`` -> ``a[1]``)."""
    out = ""
    for part in parts:
        if part:
            out += part if part.startswith("[") or not out else "." + part
    return out


def loc_text(loc: Sequence[Any]) -> str:
    """``("disturbance", "y", 0, "value_v")`` -> ``disturbance.y[0].value_v``."""
    return join(*(f"[{p}]" if isinstance(p, int) else shorten(str(p)) for p in loc))


def describe(error: dict[str, Any], component_names: bool = False, allowed: Sequence[str] = ()) -> tuple[str, str]:
    """(field path, message) of one pydantic error.

    component_names: name a vector's component ``.x`` (Python) rather than ``[0]`` (files).
    allowed: the keys an ``unexpected_keyword_argument`` could have been.
    """
    loc = list(error["loc"])
    kind = error["type"]
    ctx = error.get("ctx") or {}
    if kind == "unknown_key":
        return loc_text([*loc, str(ctx["key"])]), f"unknown key; allowed: {ctx['allowed']}"
    if kind == "unexpected_keyword_argument":
        return loc_text(loc), "unknown key" + (f"; allowed: {', '.join(allowed)}" if allowed else "")
    if kind == "missing":
        if loc and isinstance(loc[-1], int):
            return loc_text(loc[:-1]), f"too few items: item {loc[-1]} is missing"
        return loc_text(loc), "required field is missing"
    path = loc_text(loc)
    if "component" in ctx:
        path = join(path, f"{ctx['name']}" if component_names else f"[{ctx['component']}]")
    if kind == "rule":
        path = join(path, ctx["field"])
    msg = re.sub(r" or (an )?instance of \w+", "", error["msg"]).removeprefix("Value error, ")
    if kind in _SAYS_GIVEN:
        return path, _lower_first(msg)
    return path, f"{_lower_first(msg)}, got {quote(error.get('input'))}"


def _lower_first(text: str) -> str:
    return text[:1].lower() + text[1:] if text[:2] != text[:2].upper() else text


__all__ = [
    "FREQUENCY_MAX_HZ",
    "VOLTS_MAX_V",
    "Count",
    "Model",
    "Frequency",
    "LABEL_RULE",
    "Label",
    "NonNegative",
    "Number",
    "OrNamed",
    "Positive",
    "Range",
    "Real",
    "Seconds",
    "Vector",
    "Window",
    "describe",
    "interval",
    "known_keys",
    "label_from",
    "quote",
    "rule",
    "validated",
    "shorten",
]
