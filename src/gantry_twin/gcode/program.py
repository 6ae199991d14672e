"""What reading a part program gives (:class:`Program`), its one-line error and the bounded reading of a file.

Every error is a :class:`GcodeError`, one line ``FILE:LINE:COLUMN: WORD: what
is wrong`` (``FILE:LINE: WORD: ...`` where no column applies). Input is
bounded: a regular file of at most ``MAX_FILE_BYTES``, lines of at most
``MAX_LINE_CHARS``, ASCII (UTF-8 only inside comments), read in one bounded read.
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass, field

import numpy as np

from gantry_twin.gcode.geometry import Dwell, Move, bounding_box

#: Largest program file read, bytes.
MAX_FILE_BYTES = 32 * 1024 * 1024
#: Longest line, characters (LinuxCNC's LINELEN is 255).
MAX_LINE_CHARS = 256
#: Half the travel of each axis about the centre, m (the joints' range in models/gantry.xml).
TRAVEL_HALF_M = (0.255, 0.255)
#: Clearance kept between a contour and the end of travel, metres (a run's path stays within the half travel less it).
TRAVEL_MARGIN_M = 0.005


class GcodeError(ValueError):
    """A program that cannot be run: ``FILE:LINE[:COLUMN]: WORD: what is wrong`` (the CLI prints it, exits 2)."""

    def __init__(self, file: str, line: int, word: str, what: str, column: int | None = None) -> None:
        self.file, self.line, self.word, self.what, self.column = file, line, word, what, column
        where = f"{file}:{line}:{column}" if column else f"{file}:{line}"
        super().__init__(f"{where}: {word}: {what}")


@dataclass(frozen=True)
class Program:
    """A program read: its moves and dwells in order, where it starts, what was dropped and merged.

    items: :class:`Move` and :class:`Dwell`, in program order (zero-length
    moves left out), the tool centre's where cutter compensation applies.
    start_m: the point the run starts at rest (the end of a leading G0, else
    the origin). dropped: kind -> count of the words dropped with
    ``drop_unsupported``. merged: G1 lines joined to the line before by
    G64 Q. messages: the ``(print, ...)`` ``(debug, ...)`` ``(msg, ...)``
    lines, in the order they ran. programmed_moves: every move as
    programmed (before merging and compensation). blocks: blocks executed.
    """

    name: str
    items: tuple[Move | Dwell, ...]
    start_m: tuple[float, float]
    dropped: dict[str, int] = field(default_factory=dict)
    merged: int = 0
    messages: tuple[str, ...] = ()
    programmed_moves: tuple[Move, ...] = ()
    blocks: int = 0

    @property
    def moves(self) -> list[Move]:
        return [item for item in self.items if isinstance(item, Move)]


def read_bytes(path: str | os.PathLike, max_bytes: int = MAX_FILE_BYTES) -> bytes:
    """A regular file's bytes, at most ``max_bytes`` (checked before and while reading)."""
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
    return data


def text_lines(data: bytes, name: str, max_line_chars: int = MAX_LINE_CHARS) -> list[tuple[int, str]]:
    """(line number, text) of the program between its ``%`` delimiters, ASCII checked, blank lines left out."""
    out: list[tuple[int, str]] = []
    percent_open = False
    for number, raw in enumerate(data.split(b"\n"), start=1):
        if len(raw) > max_line_chars + 1:
            raise GcodeError(name, number, "line", f"longer than {max_line_chars} characters")
        for column, byte in enumerate(raw.rstrip(b"\r"), start=1):
            if byte == 127 or (byte < 32 and byte != 9):
                raise GcodeError(
                    name, number, "line", f"byte 0x{byte:02x} at column {column}: not G-code text (binary?)"
                )
        text = _ascii(raw.rstrip(b"\r"), name, number)
        stripped = text.strip()
        if stripped.startswith("%"):
            if out or percent_open:
                break  # the closing %: the program ends
            percent_open = True
            continue
        if not stripped:
            continue
        if len(stripped) > max_line_chars:
            raise GcodeError(name, number, "line", f"longer than {max_line_chars} characters")
        out.append((number, text))  # columns count from the line's first character
    return out


def _ascii(raw: bytes, name: str, number: int) -> str:
    """A line's text: ASCII, or UTF-8 whose other characters are all in comments (LinuxCNC keeps a comment's
    text as it is), each of those read as ``?``."""
    if raw.isascii():
        return raw.decode("ascii")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as error:
        byte = raw[error.start]
        raise GcodeError(
            name, number, "line", f"byte 0x{byte:02x} at column {error.start + 1}: not G-code text (binary?)"
        ) from None
    out, depth, rest = [], 0, False
    for column, char in enumerate(text, start=1):
        if not char.isascii():
            if not (depth or rest):
                raise GcodeError(name, number, "line", f"{char!r} at column {column}: not ASCII, and not in a comment")
            char = "?"
        elif char == "(" and not rest:
            depth += 1
        elif char == ")" and depth:
            depth -= 1
        elif char == ";" and not depth:
            rest = True
        out.append(char)
    return "".join(out)


def check_move(item: Move, half: tuple[float, float], name: str) -> None:
    """A move that leaves the travel (``half``: +- m per axis) is a :class:`GcodeError` at its line."""
    if item.centre_m is None:
        (x0, y0), (x1, y1) = item.start_m, item.end_m
        if abs(x0) <= half[0] and abs(x1) <= half[0] and abs(y0) <= half[1] and abs(y1) <= half[1]:
            return  # a line inside: its ends are (the common case, without numpy)
    else:
        (cx, cy), r = item.centre_m, item.radius_m
        if abs(cx) + r <= half[0] and abs(cy) + r <= half[1]:
            return  # an arc whose whole circle is inside (without numpy)
    lo, hi = bounding_box([item])
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        raise GcodeError(name, item.line, "move", "not a finite point (a number too large for the arithmetic)")
    for axis, letter in enumerate("XY"):
        if lo[axis] < -half[axis] - 1e-12 or hi[axis] > half[axis] + 1e-12:
            extreme = lo[axis] if lo[axis] < -half[axis] else hi[axis]
            raise GcodeError(
                name, item.line, letter,
                f"the move reaches {extreme * 1e3:.6g} mm, outside the travel of +-{half[axis] * 1e3:g} mm",
            )  # fmt: skip
