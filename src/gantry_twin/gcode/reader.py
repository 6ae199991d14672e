"""Reading a part program: LinuxCNC's dialect for a two-axis XY gantry, file to :class:`Program`.

The reading is in three rooms, as LinuxCNC's interpreter: the lexer
(:mod:`~gantry_twin.gcode.lexer`, values by
:mod:`~gantry_twin.gcode.expressions`) reads each line once; the
interpreter (:mod:`~gantry_twin.gcode.interpreter`: parameters, O-words,
calls) runs them; the machine state (:mod:`~gantry_twin.gcode.machine`:
modes, offsets, cycles) turns each block into moves, which the planner
receives. Everything a two-axis gantry cannot do is an error, or (the Z
axis, spindle, coolant, a drilling cycle's Z part) dropped and counted in
:attr:`Program.dropped` with ``drop_unsupported``. Moves outside the
travel are refused. Docs: docs/gcode.md (the dialect table lists every
word and construct).
"""

from __future__ import annotations

import os
from pathlib import Path

from gantry_twin.gcode.arcs import ARC_RADIUS_TOLERANCE_IN, ARC_RADIUS_TOLERANCE_MM, ARC_RELATIVE_TOLERANCE, MM_PER_INCH
from gantry_twin.gcode.geometry import Move
from gantry_twin.gcode.interpreter import MAX_BLOCKS, Interpreter, load_unit
from gantry_twin.gcode.program import (
    MAX_FILE_BYTES,
    MAX_LINE_CHARS,
    TRAVEL_HALF_M,
    GcodeError,
    Program,
    check_move,
    read_bytes,
)
from gantry_twin.gcode.tools import Tool

__all__ = [
    "ARC_RADIUS_TOLERANCE_IN",
    "ARC_RADIUS_TOLERANCE_MM",
    "ARC_RELATIVE_TOLERANCE",
    "MAX_BLOCKS",
    "MAX_FILE_BYTES",
    "MAX_LINE_CHARS",
    "MM_PER_INCH",
    "TRAVEL_HALF_M",
    "GcodeError",
    "Program",
    "parse_program",
    "read_program",
]


def read_program(
    path: str | os.PathLike,
    *,
    drop_unsupported: bool = False,
    travel_half_m: tuple[float, float] = TRAVEL_HALF_M,
    max_bytes: int = MAX_FILE_BYTES,
    max_line_chars: int = MAX_LINE_CHARS,
    **options,
) -> Program:
    """Read a program file (a regular file of at most ``max_bytes``) into a :class:`Program`.

    ``options``: ``block_delete`` (default True: skip lines starting ``/``), ``max_blocks``,
    ``subroutine_path`` (directories searched for ``NAME.ngc`` before the program's own),
    ``work_offsets_mm`` ({1: (x, y), ...}: G54 ... G59.3's offsets at the start, mm), ``tools`` (the tool table
    G41 / G42 take their tool's diameter from, :func:`gantry_twin.gcode.tools.read_tool_table`), ``merge_lines``
    (:func:`parse_program`'s).
    """
    data = read_bytes(path, max_bytes)
    return parse_program(
        data, name=str(path), drop_unsupported=drop_unsupported, travel_half_m=travel_half_m,
        max_line_chars=max_line_chars, **options,
    )  # fmt: skip


def parse_program(
    source: str | bytes,
    *,
    name: str = "<program>",
    drop_unsupported: bool = False,
    travel_half_m: tuple[float, float] = TRAVEL_HALF_M,
    max_line_chars: int = MAX_LINE_CHARS,
    block_delete: bool = True,
    max_blocks: int = MAX_BLOCKS,
    subroutine_path: tuple[str | os.PathLike, ...] = (),
    work_offsets_mm: dict[int, tuple[float, float]] | None = None,
    tools: dict[int, Tool] | None = None,
    merge_lines: bool = True,
) -> Program:
    """Parse program text (str, or bytes that must be ASCII) into a :class:`Program`; ``merge_lines`` False keeps
    every G1 line G64 Q would merge (the path as LinuxCNC's interpreter emits it, before its canon merges)."""
    data = source.encode("utf-8") if isinstance(source, str) else bytes(source)
    unit = load_unit(name, data)
    interpreter = Interpreter(
        unit, drop_unsupported=drop_unsupported, block_delete=block_delete, max_blocks=max_blocks,
        subroutine_path=tuple(Path(p) for p in subroutine_path), work_offsets_mm=work_offsets_mm,
        travel_half_m=travel_half_m, tools=tools, merge_lines=merge_lines,
    )  # fmt: skip
    program = interpreter.run()
    _check_travel(program, travel_half_m)
    return program


def _check_travel(program: Program, travel_half_m: tuple[float, float]) -> None:
    half = travel_half_m
    for item in program.items:
        if isinstance(item, Move):
            check_move(item, half, program.name)
    x, y = program.start_m
    if abs(x) > half[0] or abs(y) > half[1]:
        raise GcodeError(program.name, 0, "start", "the start point is outside the travel")
