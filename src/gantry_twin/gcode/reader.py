"""Reading a part program: the RS274/NGC subset a two-axis gantry runs (LinuxCNC's dialect).

Supported: G0, G1, G2 / G3 (centre by I J relative to the start, or R; a full
circle when the end is the start; P turns), G4 P dwell (seconds), G17,
G20 / G21, G90 / G91, G61 (exact path: stop at every corner) and G64 [P]
(blend within P), F (units per minute), N, comments ``( )`` and ``;``,
``%`` delimiters, M2 / M30. Harmless modal resets (G40 G49 G54 G80 G91.1
G94) are accepted and do nothing. Everything else is an error; the words a
gantry cannot do (Z and other axes, spindle S M3 M4 M5, tool T M6, coolant
M7 M8 M9, G43) are errors too unless ``drop_unsupported`` is set, when they
are dropped and counted in :attr:`Program.dropped`.

An arc whose end is not on its circle is refused by LinuxCNC's rule
(interp_arc.cc): the radii to start and end differ by more than
``0.02 sqrt 2`` mm (0.002 sqrt 2 in) and by more than 0.1 % of the radius,
or by more than 100 times that. Within the rule the arc keeps its start
radius and ends on its circle at the angle of the programmed end; the next
block starts there.

Every error is a :class:`GcodeError`, one line ``FILE:LINE: WORD: what is
wrong``. Input is bounded: a regular file of at most ``MAX_FILE_BYTES``,
lines of at most ``MAX_LINE_CHARS``, ASCII only, read in one bounded read.
Docs: docs/gcode.md.
"""

from __future__ import annotations

import math
import os
import re
import stat
from collections import Counter
from dataclasses import dataclass, field

from gantry_twin.gcode.geometry import Dwell, Move, bounding_box

#: Largest program file read, bytes.
MAX_FILE_BYTES = 32 * 1024 * 1024
#: Longest line, characters (LinuxCNC's LINELEN is 255).
MAX_LINE_CHARS = 256
#: Half the travel of each axis about the centre, m (the joints' range in models/gantry.xml).
TRAVEL_HALF_M = (0.255, 0.255)
#: LinuxCNC's arc tolerances (rs274ngc_interp.hh): absolute, mm; relative.
ARC_RADIUS_TOLERANCE_MM = 0.02 * math.sqrt(2.0)
ARC_RADIUS_TOLERANCE_IN = 0.002 * math.sqrt(2.0)
ARC_RELATIVE_TOLERANCE = 0.001
MM_PER_INCH = 25.4

_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)")
#: Words a two-axis gantry cannot do, by kind, dropped only on request.
_AXES = "ZABCUVW"
_DROPPABLE_M = {3: "spindle", 4: "spindle", 5: "spindle", 6: "tool change", 7: "coolant", 8: "coolant", 9: "coolant"}
_NOOP_G = {"G40", "G49", "G54", "G80", "G91.1", "G94"}
_MOTION = {"G0": 0, "G1": 1, "G2": 2, "G3": 3}
_MODAL_GROUPS = {
    "motion": {"G0", "G1", "G2", "G3"},
    "plane": {"G17", "G18", "G19"},
    "units": {"G20", "G21"},
    "distance": {"G90", "G91"},
    "path": {"G61", "G64"},
}


class GcodeError(ValueError):
    """A program that cannot be run: ``FILE:LINE: WORD: what is wrong`` (the CLI prints it and exits 2)."""

    def __init__(self, file: str, line: int, word: str, what: str) -> None:
        self.file, self.line, self.word, self.what = file, line, word, what
        super().__init__(f"{file}:{line}: {word}: {what}")


@dataclass(frozen=True)
class Program:
    """A program read: its moves and dwells in order, where it starts, what was dropped.

    items: :class:`Move` and :class:`Dwell`, in program order (zero-length
    moves left out). start_m: the point the run starts at rest (the end of
    a leading G0, else the origin). dropped: kind -> count of the words
    dropped with ``drop_unsupported``.
    """

    name: str
    items: tuple[Move | Dwell, ...]
    start_m: tuple[float, float]
    dropped: dict[str, int] = field(default_factory=dict)

    @property
    def moves(self) -> list[Move]:
        return [item for item in self.items if isinstance(item, Move)]


def read_program(
    path: str | os.PathLike,
    *,
    drop_unsupported: bool = False,
    travel_half_m: tuple[float, float] = TRAVEL_HALF_M,
    max_bytes: int = MAX_FILE_BYTES,
    max_line_chars: int = MAX_LINE_CHARS,
) -> Program:
    """Read a program file (a regular file of at most ``max_bytes``) into a :class:`Program`."""
    name = str(path)
    try:
        info = os.stat(path)
    except OSError as error:
        raise GcodeError(name, 0, "file", f"cannot be read ({error.strerror or error})") from None
    if not stat.S_ISREG(info.st_mode):
        raise GcodeError(name, 0, "file", "is not a regular file")
    if info.st_size > max_bytes:
        raise GcodeError(name, 0, "file", f"is {info.st_size} bytes, more than the {max_bytes} a program may have")
    try:
        with open(path, "rb") as handle:
            if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
                raise GcodeError(name, 0, "file", "is not a regular file")
            data = handle.read(max_bytes + 1)
    except OSError as error:
        raise GcodeError(name, 0, "file", f"cannot be read ({error.strerror or error})") from None
    if len(data) > max_bytes:
        raise GcodeError(name, 0, "file", f"is more than the {max_bytes} bytes a program may have")
    return parse_program(
        data, name=name, drop_unsupported=drop_unsupported, travel_half_m=travel_half_m, max_line_chars=max_line_chars
    )


def parse_program(
    source: str | bytes,
    *,
    name: str = "<program>",
    drop_unsupported: bool = False,
    travel_half_m: tuple[float, float] = TRAVEL_HALF_M,
    max_line_chars: int = MAX_LINE_CHARS,
) -> Program:
    """Parse program text (str, or bytes that must be ASCII) into a :class:`Program`."""
    data = source.encode("utf-8") if isinstance(source, str) else bytes(source)
    reader = _Reader(name, drop_unsupported)
    percent_open = False
    for number, raw in enumerate(data.split(b"\n"), start=1):
        if len(raw) > max_line_chars + 1:
            raise GcodeError(name, number, "line", f"longer than {max_line_chars} characters")
        text = _ascii(raw.rstrip(b"\r"), name, number)
        stripped = text.strip()
        if stripped.startswith("%"):
            if reader.started or percent_open:
                break  # the closing %: the program ends
            percent_open = True
            continue
        if not stripped:
            continue
        if len(stripped) > max_line_chars:
            raise GcodeError(name, number, "line", f"longer than {max_line_chars} characters")
        if reader.line(stripped, number):
            break
    program = reader.program()
    _check_travel(program, travel_half_m)
    return program


def _ascii(raw: bytes, name: str, number: int) -> str:
    for column, byte in enumerate(raw, start=1):
        if byte >= 127 or (byte < 32 and byte != 9):
            raise GcodeError(name, number, "line", f"byte 0x{byte:02x} at column {column}: not G-code text (binary?)")
    return raw.decode("ascii")


def _check_travel(program: Program, travel_half_m: tuple[float, float]) -> None:
    half = travel_half_m
    for item in program.items:
        if isinstance(item, Move):
            lo, hi = bounding_box([item])
            for axis, letter in enumerate("XY"):
                if lo[axis] < -half[axis] - 1e-12 or hi[axis] > half[axis] + 1e-12:
                    extreme = lo[axis] if lo[axis] < -half[axis] else hi[axis]
                    raise GcodeError(
                        program.name, item.line, letter,
                        f"the move reaches {extreme * 1e3:.6g} mm, outside the travel of +-{half[axis] * 1e3:g} mm",
                    )  # fmt: skip
    x, y = program.start_m
    if abs(x) > half[0] or abs(y) > half[1]:
        raise GcodeError(program.name, 0, "start", "the start point is outside the travel")


def _comments_removed(text: str, name: str, number: int) -> str:
    """The line without ( ) comments and the ; rest-of-line comment."""
    out = []
    i = 0
    while i < len(text):
        char = text[i]
        if char == ";":
            break
        if char == "(":
            close = text.find(")", i + 1)
            if close < 0:
                raise GcodeError(name, number, "(", "comment not closed on its line")
            if "(" in text[i + 1 : close]:
                raise GcodeError(name, number, "(", "nested comment")
            i = close + 1
            continue
        if char == ")":
            raise GcodeError(name, number, ")", "closing parenthesis without a comment")
        out.append(char)
        i += 1
    return "".join(out)


class _Reader:
    """The interpreter's modal state, one line at a time."""

    def __init__(self, name: str, drop: bool) -> None:
        self.name, self.drop = name, drop
        self.items: list[Move | Dwell] = []
        self.dropped: Counter[str] = Counter()
        self.position = (0.0, 0.0)
        self.start: tuple[float, float] | None = None
        self.started = False
        self.motion: int | None = None
        self.scale_m = 1e-3  # G21
        self.incremental = False
        self.exact_stop = False  # LinuxCNC starts in G64
        self.tolerance_m = math.inf
        self.feed_m_s: float | None = None

    def error(self, number: int, word: str, what: str) -> GcodeError:
        return GcodeError(self.name, number, word, what)

    def words(self, text: str, number: int) -> dict[str, float]:
        """The line's words, letter -> value (G and M keyed by their code, e.g. 'G1', 'M30')."""
        body = "".join(_comments_removed(text, self.name, number).split()).upper()
        if body.startswith("/"):
            raise self.error(number, "/", "block delete is not supported")
        found: dict[str, float] = {}
        codes: dict[str, set[str]] = {}
        i = 0
        while i < len(body):
            letter = body[i]
            if not letter.isalpha():
                if letter in "#[":
                    raise self.error(number, letter, "parameters and expressions are not supported")
                raise self.error(number, "line", f"expected a word (a letter and a number) at {body[i:][:12]!r}")
            match = _NUMBER.match(body, i + 1)
            if match is None:
                if body[i + 1 : i + 2] in ("#", "["):
                    raise self.error(number, body[i + 1], "parameters and expressions are not supported")
                raise self.error(number, letter, "a number must follow the letter")
            value_text = match.group()
            value = float(value_text)
            i = match.end()
            if letter in "GM":
                code = _code(letter, value_text)
                if code is None:
                    shown = letter + value_text if len(value_text) <= 12 else f"{letter}{value_text[:12]}..."
                    raise self.error(number, shown, f"unknown {letter} code")
                for group, members in _MODAL_GROUPS.items():
                    if code in members and group in codes.setdefault("groups", set()):
                        raise self.error(number, code, f"a second {group} code on the line")
                    if code in members:
                        codes["groups"].add(group)
                if code in found:
                    raise self.error(number, code, "repeated on the line")
                found[code] = 0.0
                continue
            if letter in found:
                raise self.error(number, letter, "word repeated on the line")
            if not math.isfinite(value):
                raise self.error(number, letter, "not a finite number")
            found[letter] = value
        return found

    def line(self, text: str, number: int) -> bool:
        """Execute one line; True when it ends the program (M2 / M30)."""
        words = self.words(text, number)
        self.started = self.started or bool(words)
        m_codes = [code for code in words if code.startswith("M")]
        for code in m_codes:
            value = int(code[1:])
            if value in (2, 30):
                continue
            kind = _DROPPABLE_M.get(value)
            if kind is None:
                raise self.error(number, code, "unsupported M code (only M2 and M30 end a program)")
            self._unsupported(number, code, kind)
            del words[code]
        for letter, kind in (("S", "spindle speed"), ("T", "tool"), ("H", "tool length offset")):
            if letter in words:
                self._unsupported(number, letter, kind)
                del words[letter]
        if "G43" in words:
            self._unsupported(number, "G43", "tool length offset")
            del words["G43"]
        for letter in _AXES:
            if letter in words:
                self._unsupported(number, letter, f"{letter} axis")
                del words[letter]
        if "K" in words:
            raise self.error(number, "K", "not used in the XY plane (G17): arcs take I and J")
        allowed = set("XYIJRFNP") | set(_MOTION) | {"G4", "G17", "G20", "G21", "G90", "G91", "G61", "G64"}
        allowed |= _NOOP_G | {"M2", "M30"}
        for word in words:
            if word not in allowed:
                if word in ("G18", "G19"):
                    raise self.error(number, word, "only the XY plane (G17) exists on a two-axis gantry")
                if word.startswith("G"):
                    raise self.error(number, word, "unsupported G code")
                raise self.error(number, word, "unsupported word")
        if "N" in words and (words["N"] < 0 or words["N"] != int(words["N"])):
            raise self.error(number, "N", "a line number is a whole number >= 0")
        if "F" in words:
            if words["F"] <= 0.0:
                raise self.error(number, "F", "the feed must be > 0")
        if "G20" in words:
            self.scale_m = MM_PER_INCH * 1e-3
        if "G21" in words:
            self.scale_m = 1e-3
        if "F" in words:
            self.feed_m_s = words["F"] * self.scale_m / 60.0
        if "G4" in words:
            if "P" not in words:
                raise self.error(number, "G4", "a dwell needs P (seconds)")
            if words["P"] < 0.0:
                raise self.error(number, "P", "a dwell cannot be negative")
            if words["P"] > 0.0:
                self.items.append(Dwell(words["P"], number))
        if "G61" in words:
            self.exact_stop, self.tolerance_m = True, math.inf
        if "G64" in words:
            tolerance = words.get("P", math.inf)
            if tolerance <= 0.0:
                raise self.error(number, "P", "the G64 tolerance must be > 0")
            self.exact_stop = False
            self.tolerance_m = tolerance * self.scale_m if math.isfinite(tolerance) else tolerance
        if "G90" in words:
            self.incremental = False
        if "G91" in words:
            self.incremental = True
        motion = next((code for code in words if code in _MOTION), None)
        if motion is not None:
            self.motion = _MOTION[motion]
        uses_p = "G4" in words or "G64" in words
        axes = any(letter in words for letter in "XY")
        if "P" in words and not uses_p and not (self.motion in (2, 3) and (axes or "I" in words or "J" in words)):
            raise self.error(number, "P", "P only follows G4, G64 or an arc (turns)")
        if not axes and any(letter in words for letter in "IJR"):
            if self.motion in (2, 3) and "R" not in words:
                axes = True  # a full circle: I J without X Y
            else:
                raise self.error(number, next(c for c in "IJR" if c in words), "needs an arc with X or Y")
        if axes:
            self._move(words, number)
        return "M2" in words or "M30" in words

    def _unsupported(self, number: int, word: str, kind: str) -> None:
        if not self.drop:
            raise self.error(number, word, f"{kind}: a two-axis gantry cannot do this (drop_unsupported drops it)")
        self.dropped[kind] += 1

    def _target(self, words: dict[str, float]) -> tuple[float, float]:
        x, y = self.position
        s = self.scale_m
        if self.incremental:
            return x + words.get("X", 0.0) * s, y + words.get("Y", 0.0) * s
        return (words["X"] * s if "X" in words else x), (words["Y"] * s if "Y" in words else y)

    def _move(self, words: dict[str, float], number: int) -> None:
        if self.motion is None:
            raise self.error(number, "X" if "X" in words else "Y", "an axis word without G0, G1, G2 or G3 in force")
        end = self._target(words)
        rapid = self.motion == 0
        if not rapid and self.feed_m_s is None:
            raise self.error(number, f"G{self.motion}", "no feed: F must be given before the first feed move")
        if not self.items and rapid and self.start is None:
            self.start = self.position = end  # the run starts at rest after its first G0
            return
        if self.start is None:
            self.start = self.position
        common = dict(
            feed_m_s=math.inf if rapid else self.feed_m_s, rapid=rapid, line=number,
            exact_stop=self.exact_stop, tolerance_m=self.tolerance_m,
        )  # fmt: skip
        if self.motion in (0, 1):
            if "I" in words or "J" in words or "R" in words:
                raise self.error(number, "I" if "I" in words else "J" if "J" in words else "R", "only arcs take it")
            if end != self.position:
                self.items.append(Move("line", self.position, end, **common))
            self.position = end
            return
        move = self._arc(words, number, end, common)
        self.items.append(move)
        self.position = move.end_m

    def _arc(self, words: dict[str, float], number: int, end: tuple[float, float], common: dict) -> Move:
        start = self.position
        s = self.scale_m
        ccw = self.motion == 3
        word = f"G{self.motion}"
        turns = words.get("P", 1.0)
        if turns < 1 or turns != int(turns):
            raise self.error(number, "P", "arc turns must be a whole number >= 1")
        has_ij = "I" in words or "J" in words
        if has_ij and "R" in words:
            raise self.error(number, "R", "an arc takes I J or R, not both")
        if not has_ij and "R" not in words:
            raise self.error(number, word, "an arc needs its centre (I J) or its radius (R)")
        chord = math.hypot(end[0] - start[0], end[1] - start[1])
        unit = "in" if s != 1e-3 else "mm"
        tolerance_abs_m = (ARC_RADIUS_TOLERANCE_IN * MM_PER_INCH if unit == "in" else ARC_RADIUS_TOLERANCE_MM) * 1e-3
        if has_ij:
            centre = (start[0] + words.get("I", 0.0) * s, start[1] + words.get("J", 0.0) * s)
            r1 = math.hypot(start[0] - centre[0], start[1] - centre[1])
            r2 = math.hypot(end[0] - centre[0], end[1] - centre[1])
            if r1 <= 1e-9 or r2 <= 1e-9:
                raise self.error(number, "I" if "I" in words else "J", "zero-radius arc (centre on an end point)")
            err = abs(r1 - r2)
            if err > 100.0 * tolerance_abs_m or (err > tolerance_abs_m and err / max(r1, r2) > ARC_RELATIVE_TOLERANCE):
                raise self.error(
                    number, word,
                    f"the end is not on the arc's circle: radius {r1 / s:.6g} {unit} at the start, "
                    f"{r2 / s:.6g} {unit} at the end",
                )  # fmt: skip
        else:
            radius = words["R"] * s
            if chord <= 1e-12:
                raise self.error(number, "R", "a full circle needs I J (R cannot place its centre)")
            if abs(radius) < 1e-12:
                raise self.error(number, "R", "zero radius")
            half = 0.5 * chord
            if half > abs(radius) * (1.0 + 1e-9) + tolerance_abs_m * 1e-3:
                raise self.error(number, "R", "radius too small to reach the end point")
            height = math.sqrt(max(radius * radius - half * half, 0.0))
            mid = (0.5 * (start[0] + end[0]), 0.5 * (start[1] + end[1]))
            # The centre to the right of start->end for G2 with R > 0 (arc <= 180 deg), left for G3.
            left = (-(end[1] - start[1]) / chord, (end[0] - start[0]) / chord)
            side = (1.0 if ccw else -1.0) * (1.0 if radius > 0 else -1.0)
            centre = (mid[0] + side * height * left[0], mid[1] + side * height * left[1])
        a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
        a1 = math.atan2(end[1] - centre[1], end[0] - centre[0])
        sweep = (a1 - a0) if ccw else (a0 - a1)
        sweep = math.fmod(sweep, 2.0 * math.pi)
        if sweep < 0.0:
            sweep += 2.0 * math.pi
        if sweep < 1e-12 or (chord <= tolerance_abs_m and has_ij and sweep > 2.0 * math.pi - 1e-6):
            sweep = 2.0 * math.pi  # the end is the start: a full circle
        sweep += 2.0 * math.pi * (turns - 1)
        move = Move("arc", start, end, centre_m=centre, sweep_rad=sweep if ccw else -sweep, **common)
        on_circle = move.arc_end_m
        if math.hypot(on_circle[0] - end[0], on_circle[1] - end[1]) > 1e-12:
            end = (float(on_circle[0]), float(on_circle[1]))
        return Move("arc", start, end, centre_m=centre, sweep_rad=move.sweep_rad, **common)

    def program(self) -> Program:
        start = self.start if self.start is not None else self.position
        return Program(self.name, tuple(self.items), start, dict(self.dropped))


def _code(letter: str, value_text: str) -> str | None:
    """'G' '01' -> 'G1', 'G' '91.1' -> 'G91.1'; None for a malformed code."""
    number = float(value_text)
    if number < 0 or number >= 1000:
        return None
    if number == int(number):
        return f"{letter}{int(number)}"
    tenths = round(number * 10)
    if abs(number * 10 - tenths) > 1e-9:
        return None
    return f"{letter}{tenths // 10}.{tenths % 10}"
