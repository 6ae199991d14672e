"""The tool table: LinuxCNC's format, read into the diameters cutter radius compensation (G41 / G42) uses.

One tool a line, fields a letter and a number separated by spaces or tabs,
a remark after ``;`` (LinuxCNC's docs, "Tool Table Format")::

    T1 P1 D3.0 Z+0.0 ;3 mm end mill
    ; a line that starts with a semicolon is ignored

``T`` tool number (required, a whole number >= 0, unique), ``P`` pocket
(required, a whole number >= 0; LinuxCNC's own sample tables hold P99999,
and pockets are not unique in its lathe wear tables), ``D`` diameter, ``X Y
Z A B C U V W`` offsets, ``I J`` front and back angle (lathe), ``Q``
orientation (lathe, 0 to 9). Whole numbers may be written ``2.0``, as
LinuxCNC's ``%d`` reads them (and its tables write Q0.0); ``2.5`` is
refused. Lengths are in the machine's units, mm; only D is used here
(``diameter_m``), the others are read and checked. A negative D is allowed,
as in LinuxCNC: it is the difference to a nominal diameter, and G41 with it
cuts on the other side (:func:`gantry_twin.gcode.compensation.compensate`).
LinuxCNC skips a line it cannot read with a message; here it is an error,
so a typo cannot silently drop a tool.

Every error is a :class:`~gantry_twin.gcode.reader.GcodeError`, one line
``FILE:LINE: FIELD: what is wrong`` with the allowed range. The file comes
through the input door (:func:`gantry_twin.inputs.read_input_file`: a
regular file, at most ``INPUT_MAX_BYTES``, UTF-8). Docs: docs/gcode.md.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

from gantry_twin.gcode.program import GcodeError
from gantry_twin.inputs import InputFileError, read_input_file

#: The largest tool and pocket number (a C int, as LinuxCNC reads them).
NUMBER_MAX = 2**31 - 1
#: The largest |D|, mm: a cutter wider than a metre on a 510 mm gantry is a typo (inches? metres?).
DIAMETER_MAX_MM = 1000.0
#: The lathe orientations Q (LinuxCNC: 0 to 9; 0 and 9 are a mill's).
ORIENTATIONS = range(10)

_WHOLE = re.compile(r"([+-]?\d+)(?:\.0*)?")
_REAL = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_OFFSETS = "XYZABCUVW"
_FIELDS = "TP" + _OFFSETS + "DIJQ"
_WHAT = "a LinuxCNC tool table (lines like T1 P1 D3.0 ;comment)"


@dataclass(frozen=True, slots=True)
class Tool:
    """One tool of the table: its number, pocket, diameter (m, may be negative) and lathe orientation."""

    number: int
    pocket: int
    diameter_m: float
    orientation: int = 0
    comment: str = ""
    line: int = 0

    @property
    def radius_m(self) -> float:
        return 0.5 * self.diameter_m


def read_tool_table(path: str | os.PathLike) -> dict[int, Tool]:
    """Read a tool table file: tool number -> :class:`Tool`."""
    name = str(path)
    try:
        text = read_input_file(path, _WHAT)
    except InputFileError as error:
        raise GcodeError(name, 0, "file", str(error)) from None
    return parse_tool_table(text, name=name)


def parse_tool_table(text: str, *, name: str = "<tool table>") -> dict[int, Tool]:
    """Parse tool table text: tool number -> :class:`Tool` (in file order)."""
    tools: dict[int, Tool] = {}
    for number, raw in enumerate(text.split("\n"), start=1):
        data, _, comment = raw.rstrip("\r").partition(";")
        if not data.strip():
            continue
        tool = _tool(data, comment.strip(), name, number)
        if tool.number in tools:
            first = tools[tool.number].line
            raise GcodeError(name, number, "T", f"tool {tool.number} is already on line {first} (numbers are unique)")
        tools[tool.number] = tool
    return tools


def _tool(data: str, comment: str, name: str, number: int) -> Tool:
    values: dict[str, float] = {}
    for token in data.split():
        letter, text = token[0].upper(), token[1:]
        if letter not in _FIELDS:
            shown = token if len(token) <= 12 else token[:12] + "..."
            raise GcodeError(name, number, shown, f"unknown field; a tool line has {' '.join(_FIELDS)} and ;remark")
        if letter in values:
            raise GcodeError(name, number, letter, "given twice on the line")
        values[letter] = _value(letter, text, name, number)
    for letter, what in (("T", "the tool number"), ("P", "the pocket")):
        if letter not in values:
            raise GcodeError(name, number, letter, f"missing: every tool line gives T and P ({what})")
    return Tool(
        number=int(values["T"]), pocket=int(values["P"]), diameter_m=values.get("D", 0.0) * 1e-3,
        orientation=int(values.get("Q", 0)), comment=comment, line=number,
    )  # fmt: skip


def _value(letter: str, text: str, name: str, number: int) -> float:
    shown = text if len(text) <= 20 else text[:20] + "..."
    if letter in "TPQ":
        low, high, what = {
            "T": (0, NUMBER_MAX, "the tool number"),
            "P": (0, NUMBER_MAX, "the pocket"),
            "Q": (ORIENTATIONS[0], ORIENTATIONS[-1], "the lathe orientation"),
        }[letter]
        whole = _WHOLE.fullmatch(text)
        if whole is None or not low <= int(whole.group(1)) <= high:
            raise GcodeError(name, number, letter, f"{what} is a whole number {low} to {high}, got {shown!r}")
        return int(whole.group(1))
    ok = _REAL.fullmatch(text) is not None and math.isfinite(float(text))
    if letter == "D":
        if not ok or abs(float(text)) > DIAMETER_MAX_MM:
            raise GcodeError(
                name, number, "D", f"the diameter is a number from {-DIAMETER_MAX_MM:g} to {DIAMETER_MAX_MM:g} mm, "
                f"got {shown!r}",
            )  # fmt: skip
    elif not ok:
        kind = "an offset (mm)" if letter in _OFFSETS else "an angle (deg)"
        raise GcodeError(name, number, letter, f"{kind} is a finite number, got {shown!r}")
    return float(text)


def tool_for_compensation(
    tools: dict[int, Tool], d_word: float | None, loaded: int | None, *, file: str, line: int, code: str = "G41"
) -> Tool:
    """The tool G41 / G42 uses (LinuxCNC's rules): D names a tool number; no D (or D0) the one loaded by T.. M6.

    ``loaded``: the tool number of the last ``T.. M6`` (None: none yet). Unlike LinuxCNC, which compensates
    by a radius of 0 when no tool is loaded (so does nothing), no tool is an error here: the program asked
    for compensation and would be cut uncompensated.
    """
    if d_word is not None:
        if d_word != int(d_word) or d_word < 0:
            raise GcodeError(file, line, "D", f"{code} takes a tool number, a whole number >= 0, got {d_word:g}")
        if int(d_word) != 0:
            return _lookup(tools, int(d_word), file, line, "D")
    if loaded is None:
        raise GcodeError(file, line, code, "no tool: give D (a tool of the tool table) or load one with T.. M6")
    return _lookup(tools, loaded, file, line, code)


def _lookup(tools: dict[int, Tool], number: int, file: str, line: int, word: str) -> Tool:
    tool = tools.get(number)
    if tool is None:
        known = ", ".join(str(n) for n in list(tools)[:10]) + (", ..." if len(tools) > 10 else "")
        table = f"the tool table has {known}" if tools else "no tool table was given (--tool-table FILE)"
        raise GcodeError(file, line, word, f"tool {number} is not in the tool table ({table})")
    if tool.orientation not in (0, 9):
        raise GcodeError(file, line, word, f"tool {number} is a lathe tool (Q{tool.orientation}): no XZ plane here")
    return tool


def write_tool(tools: dict[int, Tool], number: int, words: dict[str, float], scale_m: float, error) -> None:
    """G10 L1 / L10 / L11 P``number``: write the tool's entry in ``tools`` (LinuxCNC's G10 L1): R its radius
    (program units; the diameter is 2 R), Q its orientation; a tool not in the table is added (pocket = its
    number). The offsets (X Y Z ..., and L10 / L11's from the current point) are read and not used: the tool
    length offset (G43) is dropped on an XY machine. ``error(word, what)`` makes the one-line error."""
    old = tools.get(number, Tool(number=number, pocket=number, diameter_m=0.0))
    diameter_m = old.diameter_m
    if "R" in words:
        diameter_m = 2.0 * words["R"] * scale_m
        if abs(diameter_m) * 1e3 > DIAMETER_MAX_MM:
            raise error("R", f"the radius is at most {DIAMETER_MAX_MM / 2:g} mm, got {words['R']:g}")
    orientation = old.orientation
    if "Q" in words:
        if words["Q"] != int(words["Q"]) or int(words["Q"]) not in ORIENTATIONS:
            raise error("Q", f"the lathe orientation is a whole number 0 to {ORIENTATIONS[-1]}, got {words['Q']:g}")
        orientation = int(words["Q"])
    tools[number] = Tool(number, old.pocket, diameter_m, orientation, old.comment, old.line)
