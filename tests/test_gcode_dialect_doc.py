"""docs/gcode.md's dialect table is gantry_twin.gcode.dialect's, and each entry says what the reader does."""

from __future__ import annotations

from pathlib import Path

import pytest

from gantry_twin.gcode import GcodeError, parse_program
from gantry_twin.gcode.dialect import DIALECT, EXAMPLE_TOOLS, dialect_table
from gantry_twin.gcode.machine import DROPPABLE_M, READ_G, READ_M, REFUSED_G
from gantry_twin.gcode.tools import parse_tool_table

DOC = Path(__file__).resolve().parents[1] / "docs" / "gcode.md"


@pytest.mark.parametrize("entry", DIALECT, ids=[e.word for e in DIALECT])
def test_each_entry_does_what_the_table_says(entry):
    if entry.status == "read":
        program = parse_program(entry.example, name="d.ngc", tools=parse_tool_table(EXAMPLE_TOOLS))
        assert program.dropped == {}
    elif entry.status == "dropped":
        with pytest.raises(GcodeError, match=f"{entry.what.split(';')[0].replace('(', '.').replace(')', '.')}"):
            parse_program(entry.example, name="d.ngc")
        assert parse_program(entry.example, name="d.ngc", drop_unsupported=True).dropped
    else:
        assert entry.status == "refused"
        with pytest.raises(GcodeError) as info:
            parse_program(entry.example, name="d.ngc", drop_unsupported=True)
        assert entry.what in str(info.value)


def test_the_table_names_every_code_the_reader_knows():
    listed = {word for e in DIALECT for word in e.word.split()}
    known = READ_G | READ_M | set(REFUSED_G) | {f"M{n}" for n in DROPPABLE_M} | {"G43", "G96"}
    assert sorted(known - listed) == []


def test_docs_gcode_md_shows_the_table():
    text = DOC.read_text(encoding="utf-8")
    assert dialect_table() in text, "docs/gcode.md: paste gantry_twin.gcode.dialect.dialect_table()'s output"
