"""One line of a part program read into its parts: block delete, O-word, parameter settings, words, messages.

LinuxCNC's line (overview, "Format of a Line"): an optional block delete
``/``, an optional line number ``N``, then words (a letter and a real value),
parameter settings ``#n=value`` / ``#<name>=value`` and comments, or an
O-word line ``O<name> keyword [args]``. Spaces are ignored outside comments
and case does not matter. ``(print, ...)``, ``(debug, ...)`` and
``(msg, ...)`` comments are kept as messages. Values are read by
:mod:`gantry_twin.gcode.expressions`; the line is read once and its values
evaluated each time it runs.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from gantry_twin.gcode.expressions import Reader, ReadError, Value

#: O-word keywords (LinuxCNC's O codes).
O_KEYWORDS = (
    "sub", "endsub", "call", "return", "if", "elseif", "else", "endif",
    "while", "endwhile", "do", "repeat", "endrepeat", "break", "continue",
)  # fmt: skip
_MESSAGE = re.compile(r"\(\s*(print|debug|msg)\s*,(.*)\)\s*$", re.IGNORECASE | re.DOTALL)
_LABEL = re.compile(r"<([^<>]*)>|(\d+)")


@dataclass(frozen=True, slots=True)
class Word:
    letter: str  # 'G', 'M', 'X', ...
    value: Value | float
    column: int


@dataclass(frozen=True, slots=True)
class Assignment:
    target: Value | float | str  # a parameter number (value) or a name (str)
    value: Value | float
    column: int


@dataclass(frozen=True, slots=True)
class OWord:
    label: str  # 'o<name>' lower case, or 'o100'
    keyword: str
    args: tuple[Value | float, ...]
    column: int


@dataclass(slots=True)
class Line:
    number: int
    block_delete: bool = False
    words: list[Word] = field(default_factory=list)
    assignments: list[Assignment] = field(default_factory=list)
    oword: OWord | None = None
    messages: list[tuple[str, str]] = field(default_factory=list)
    #: (words, columns) of a line of constant X Y F @ ^ words only, each once (the interpreter's fast path)
    constant: tuple[dict[str, float], dict[str, int]] | None = None

    @property
    def empty(self) -> bool:
        return not (self.words or self.assignments or self.oword or self.messages)


def _compact(text: str, line: Line) -> tuple[str, list[int]]:
    """The line without comments and spaces, upper case, and the 1-based column of each kept character."""
    out: list[str] = []
    columns: list[int] = []
    i = 0
    while i < len(text):
        char = text[i]
        if char == ";":
            break
        if char == "(":
            close = text.find(")", i + 1)
            if close < 0:
                raise ReadError(i + 1, "(", "comment not closed on its line")
            if "(" in text[i + 1 : close]:
                raise ReadError(i + 1, "(", "nested comment")
            match = _MESSAGE.match(text[i : close + 1])
            if match:
                line.messages.append((match.group(1).lower(), match.group(2).strip()))
            i = close + 1
            continue
        if char == ")":
            raise ReadError(i + 1, ")", "closing parenthesis without a comment")
        if not char.isspace():
            out.append(char.upper())
            columns.append(i + 1)
        i += 1
    return "".join(out), columns


def lex(text: str, number: int) -> Line:
    """Read one line's text (raises :class:`ReadError` with the column)."""
    line = Line(number)
    body, columns = _compact(text, line)
    reader = Reader(body, columns)
    i = 0
    if body.startswith("/"):
        line.block_delete = True
        i = 1
    if body[i : i + 1] == "N":
        match = re.compile(r"\d+(?:\.\d*)?").match(body, i + 1)
        if match is None:
            raise reader.error(i, "N", "a line number is a whole number >= 0")
        i = match.end()
    if body[i : i + 1] == "O":
        line.oword = _oword(reader, i)
        return line
    while i < len(body):
        char = body[i]
        if char == "#":
            i = _assignment(reader, i, line)
            continue
        if not (char.isalpha() or char in "@^$"):
            raise reader.error(i, "line", f"expected a word (a letter and a number) at {body[i:][:12]!r}")
        if char == "O":
            raise reader.error(i, "O", "an O-word must begin its line")
        if i + 1 >= len(body):
            raise reader.error(i, char, "a number must follow the letter")
        nxt = body[i + 1]
        if not (nxt.isdigit() or nxt in ".+-#["):
            if char == "N":
                raise reader.error(i, "N", "a line number begins the line")
            raise reader.error(i, char, "a number must follow the letter")
        value, end = reader.value(i + 1)
        line.words.append(Word(char, value, reader.column(i)))
        i = end
    letters = [w.letter for w in line.words]
    if (
        letters and not line.assignments and not line.messages and len(set(letters)) == len(letters)
        and all(isinstance(w.value, float) and w.letter in "XYF@^" for w in line.words)
    ):  # fmt: skip
        line.constant = ({w.letter: w.value for w in line.words}, {w.letter: w.column for w in line.words})
    return line


def _assignment(reader: Reader, i: int, line: Line) -> int:
    body = reader.text
    column = reader.column(i)
    if body[i + 1 : i + 2] == "<":
        close = body.find(">", i + 2)
        if close < 0:
            raise reader.error(i, "#<", "named parameter not closed with >")
        target: Value | float | str = body[i + 2 : close].lower()
        if not target:
            raise reader.error(i, "#<>", "empty parameter name")
        end = close + 1
    else:
        target, end = reader.value(i + 1)
    if body[end : end + 1] != "=":
        raise reader.error(i, "#", "a parameter on its own: expected #n=value (a value is used after a letter)")
    value, end = reader.value(end + 1)
    line.assignments.append(Assignment(target, value, column))
    return end


def _oword(reader: Reader, i: int) -> OWord:
    body = reader.text
    column = reader.column(i)
    match = _LABEL.match(body, i + 1)
    if match is None:
        raise reader.error(i, "O", "an O-word needs a number or a <name>")
    label = f"o<{match.group(1).lower()}>" if match.group(1) is not None else f"o{int(match.group(2))}"
    j = match.end()
    keyword = next((k for k in sorted(O_KEYWORDS, key=len, reverse=True) if body.startswith(k.upper(), j)), None)
    if keyword is None:
        raise reader.error(j, label, f"unknown O-word keyword (known: {' '.join(O_KEYWORDS)})")
    j += len(keyword)
    args: list[Value | float] = []
    while j < len(body):
        if body[j] != "[":
            raise reader.error(j, keyword, "arguments of an O-word are expressions in [ ]")
        value, j = reader.bracket(j)
        args.append(value)
    takes = {"call": 30, "return": 1, "endsub": 1, "if": 1, "elseif": 1, "while": 1, "repeat": 1}
    if len(args) > takes.get(keyword, 0):
        raise reader.error(i, keyword, f"takes at most {takes.get(keyword, 0)} [argument]s")
    if keyword in ("if", "elseif", "while", "repeat") and not args:
        raise reader.error(i, keyword, "needs a condition [...]" if keyword != "repeat" else "needs a count [...]")
    return OWord(label, keyword, tuple(args), column)
