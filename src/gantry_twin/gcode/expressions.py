"""Expressions and parameter references of LinuxCNC's dialect, read into small closures.

A value on a line is a number (``-1.5``), a parameter (``#3``, ``#<name>``,
``#<_global>``, ``#[1+2]``: the parameter whose number is the value), an expression in brackets or a unary
function (``SIN[30]``, ``ATAN[1]/[2]``, ``EXISTS[#<x>]``). Inside brackets the
binary operators bind, tightest first: ``**``; ``* / MOD``; ``+ -``;
``EQ NE GT GE LT LE``; ``AND OR XOR``; left to right within a level (LinuxCNC's
overview, "Binary Operators"). Angles are degrees; EQ and NE compare within
0.0001 as LinuxCNC's ``TOLERANCE_EQUAL``; MOD's result takes the divisor's
sign as LinuxCNC's (``fmod``, plus ``|b|`` when negative); ROUND rounds halves
away from zero. A reader returns a closure ``value(scope) -> float``; the
scope (the interpreter) answers ``numbered(n, column)`` and
``named(name, column)`` and raises ``error(column, word, what)``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any

Value = Callable[[Any], float]

#: LinuxCNC's TOLERANCE_EQUAL for EQ and NE.
EQUAL_TOLERANCE = 0.0001
NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)")
_NAME = re.compile(r"<([^<>]*)>")
_BINARY = (
    ("AND", "OR", "XOR"),
    ("EQ", "NE", "GT", "GE", "LT", "LE"),
    ("+", "-"),
    ("*", "/", "MOD"),
    ("**",),
)
_OPERATORS = sorted({op for level in _BINARY for op in level}, key=len, reverse=True)
FUNCTIONS = ("ABS", "ACOS", "ASIN", "ATAN", "COS", "EXP", "FIX", "FUP", "LN", "ROUND", "SIN", "SQRT", "TAN", "EXISTS")


class ReadError(ValueError):
    """A malformed expression at ``column`` (1-based), ``word`` the token, ``what`` the reason."""

    def __init__(self, column: int, word: str, what: str) -> None:
        self.column, self.word, self.what = column, word, what
        super().__init__(what)


def _round(value: float) -> float:
    return float(math.floor(value + 0.5)) if value >= 0 else -float(math.floor(-value + 0.5))


def _checked(name: str, fn: Callable[[float], float], ok: Callable[[float], bool], why: str):
    def apply(scope, column, value):
        if not ok(value):
            raise scope.error(column, name, f"{why} (got {value:.6g})")
        return fn(value)

    return apply


_UNARY = {
    "ABS": lambda s, c, v: abs(v),
    "ACOS": _checked("ACOS", lambda v: math.degrees(math.acos(v)), lambda v: -1 <= v <= 1, "needs -1..1"),
    "ASIN": _checked("ASIN", lambda v: math.degrees(math.asin(v)), lambda v: -1 <= v <= 1, "needs -1..1"),
    "COS": lambda s, c, v: math.cos(math.radians(v)),
    "EXP": _checked("EXP", math.exp, lambda v: v < 709.0, "overflows"),
    "FIX": lambda s, c, v: float(math.floor(v)),
    "FUP": lambda s, c, v: float(math.ceil(v)),
    "LN": _checked("LN", math.log, lambda v: v > 0, "needs a value > 0"),
    "ROUND": lambda s, c, v: _round(v),
    "SIN": lambda s, c, v: math.sin(math.radians(v)),
    "SQRT": _checked("SQRT", math.sqrt, lambda v: v >= 0, "needs a value >= 0"),
    "TAN": lambda s, c, v: math.tan(math.radians(v)),
}


def _binary(op: str, left: Value, right: Value, column: int) -> Value:
    if op == "+":
        return lambda s: left(s) + right(s)
    if op == "-":
        return lambda s: left(s) - right(s)
    if op == "*":
        return lambda s: left(s) * right(s)
    if op in ("/", "MOD"):

        def divide(s):
            a, b = left(s), right(s)
            if b == 0.0:
                raise s.error(column, op, "division by zero")
            if op == "/":
                return a / b
            r = math.fmod(a, b)
            return r + abs(b) if r < 0 else r

        return divide
    if op == "**":

        def power(s):
            a, b = left(s), right(s)
            if a < 0 and b != int(b):
                raise s.error(column, "**", f"a negative base to a fractional power ({a:.6g} ** {b:.6g})")
            try:
                return float(a**b)
            except (OverflowError, ZeroDivisionError):
                raise s.error(column, "**", "the power overflows or divides by zero") from None

        return power
    compare = {
        "EQ": lambda a, b: abs(a - b) < EQUAL_TOLERANCE,
        "NE": lambda a, b: abs(a - b) >= EQUAL_TOLERANCE,
        "GT": lambda a, b: a > b,
        "GE": lambda a, b: a >= b,
        "LT": lambda a, b: a < b,
        "LE": lambda a, b: a <= b,
        "AND": lambda a, b: a != 0 and b != 0,
        "OR": lambda a, b: a != 0 or b != 0,
        "XOR": lambda a, b: (a != 0) != (b != 0),
    }[op]
    return lambda s: 1.0 if compare(left(s), right(s)) else 0.0


class Reader:
    """Reads values from one line's text (upper case, spaces removed); ``offset`` maps an index to a column."""

    def __init__(self, text: str, columns: list[int]) -> None:
        self.text, self.columns = text, columns

    def column(self, i: int) -> int:
        return self.columns[i] if i < len(self.columns) else (self.columns[-1] + 1 if self.columns else 1)

    def error(self, i: int, word: str, what: str) -> ReadError:
        return ReadError(self.column(i), word, what)

    def value(self, i: int) -> tuple[Value | float, int]:
        """A real value at ``i``: (a float when constant, else a closure; the index after it)."""
        text = self.text
        char = text[i : i + 1]
        if char == "[":
            return self.bracket(i)
        if char == "#":
            return self.parameter(i)
        after = text[i + 1 : i + 2]
        if (char in ("+", "-") and after and (after in "[#" or after.isalpha())) or char.isalpha():
            if char in "+-":
                inner, end = self.value(i + 1)
                if char == "+":
                    return inner, end
                return (-inner if isinstance(inner, float) else (lambda s, f=inner: -f(s))), end
            return self.function(i)
        match = NUMBER.match(text, i)
        if match is None:
            shown = text[i : i + 8] or "end of line"
            raise self.error(i, shown, "expected a number, a parameter (#) or an expression ([...])")
        return float(match.group()), match.end()

    def parameter(self, i: int) -> tuple[Value, int]:
        """``#n``, ``#<name>``, ``#[expr]``, ``##n`` (the parameter whose number is parameter n)."""
        column = self.column(i)
        if self.text[i + 1 : i + 2] == "<":
            match = _NAME.match(self.text, i + 1)
            if match is None:
                raise self.error(i, "#<", "named parameter not closed with >")
            name = match.group(1).lower()
            if not name:
                raise self.error(i, "#<>", "empty parameter name")
            return (lambda s: s.named(name, column)), match.end()
        index, end = self.value(i + 1)
        if isinstance(index, float):
            number = index
            return (lambda s: s.numbered(number, column)), end
        return (lambda s: s.numbered(index(s), column)), end

    def bracket(self, i: int) -> tuple[Value | float, int]:
        value, end = self.expression(i + 1)
        if self.text[end : end + 1] != "]":
            raise self.error(i, "[", "expression not closed with ]")
        return value, end + 1

    def function(self, i: int) -> tuple[Value, int]:
        match = re.compile(r"[A-Z]+").match(self.text, i)
        assert match is not None
        name = match.group()
        column = self.column(i)
        text = self.text
        known = next((f for f in FUNCTIONS if name.startswith(f) and text[i + len(f) : i + len(f) + 1] == "["), None)
        if known is None:
            raise self.error(i, name[:12], f"unknown function (known: {' '.join(FUNCTIONS)})")
        start = i + len(known)
        if known == "EXISTS":
            match = re.compile(r"\[#<([^<>]*)>\]").match(self.text, start)
            if match is None:
                raise self.error(start, "EXISTS", "takes a named parameter: EXISTS[#<name>]")
            name_ = match.group(1).lower()
            return (lambda s: 1.0 if s.exists(name_) else 0.0), match.end()
        argument, end = self.bracket(start)
        arg = _closure(argument)
        if known == "ATAN":
            if self.text[end : end + 2] != "/[":
                raise self.error(end, "ATAN", "takes two arguments: ATAN[y]/[x]")
            x_arg, end = self.bracket(end + 1)
            x = _closure(x_arg)
            return (lambda s: math.degrees(math.atan2(arg(s), x(s)))), end
        fn = _UNARY[known]
        return (lambda s: fn(s, column, arg(s))), end

    def expression(self, i: int) -> tuple[Value | float, int]:
        """Operands and binary operators up to the closing bracket, by precedence (shunting by levels)."""
        operands: list[Value | float] = []
        operators: list[tuple[str, int]] = []
        value, i = self.value(i)
        operands.append(value)
        while True:
            op = next((o for o in _OPERATORS if self.text.startswith(o, i)), None)
            if op is None:
                break
            operators.append((op, self.column(i)))
            value, i = self.value(i + len(op))
            operands.append(value)
        return _fold(operands, operators, 0), i


def _level(op: str) -> int:
    return next(n for n, ops in enumerate(_BINARY) if op in ops)


def _fold(operands: list, operators: list[tuple[str, int]], level: int) -> Value | float:
    """Combine ``operands`` joined by ``operators``, splitting at the loosest level first (left associative)."""
    if not operators:
        return operands[0]
    for lev in range(level, len(_BINARY)):
        cuts = [k for k, (op, _) in enumerate(operators) if _level(op) == lev]
        if cuts:
            break
    parts: list[Value | float] = []
    start = 0
    for k in [*cuts, len(operators)]:
        parts.append(_fold(operands[start : k + 1], operators[start:k], lev + 1))
        start = k + 1
    result = parts[0]
    for k, part in zip(cuts, parts[1:], strict=True):
        op, column = operators[k]
        combined = _binary(op, _closure(result), _closure(part), column)
        result = _constant(combined) if isinstance(result, float) and isinstance(part, float) else combined
    return result


class _NoScope:
    def error(self, column: int, word: str, what: str) -> ReadError:
        return ReadError(column, word, what)


def _constant(value: Value) -> float | Value:
    """Fold a closure of constants into a float (its errors, if any, stay for run time)."""
    try:
        return float(value(_NoScope()))
    except ReadError:
        return value


def _closure(value: Value | float) -> Value:
    if isinstance(value, float):
        return lambda s: value
    return value


def evaluate(value: Value | float, scope: Any) -> float:
    return value if isinstance(value, float) else value(scope)
