"""The tool table (gantry_twin.gcode.tools): LinuxCNC's format read, and one line for each thing refused."""

from __future__ import annotations

import os
import re

import pytest

from gantry_twin.gcode import GcodeError
from gantry_twin.gcode.tools import DIAMETER_MAX_MM, Tool, parse_tool_table, read_tool_table, tool_for_compensation

#: FILE:LINE: FIELD: what is wrong
ONE_LINE = re.compile(r"^[^\n:]+:\d+: [^\n:]+: [^\n]+$")

TABLE = """; my mill
T1 P1 D3.0 Z+0.0 ;3 mm end mill
T2\tP17  X0 Y0 Z12.5 A0 B0 C0 U0 V0 W0 D6.35 I0 J0 Q0 ;1/4" Schaftfräser

t32 p32 d-0.02 ;nominal path, 0.02 mm under size
T0 P0 D0 Q9.0
"""


def test_a_table_in_linuxcnc_format():
    tools = parse_tool_table(TABLE, name="tool.tbl")
    assert list(tools) == [1, 2, 32, 0]
    assert tools[1] == Tool(1, 1, 3e-3, 0, "3 mm end mill", 2)
    assert tools[1].radius_m == pytest.approx(1.5e-3)
    assert tools[2].diameter_m == pytest.approx(6.35e-3) and tools[2].pocket == 17
    assert tools[2].comment == '1/4" Schaftfräser'
    assert tools[32].diameter_m == pytest.approx(-0.02e-3)  # negative: compensate cuts on the other side
    assert tools[0].orientation == 9 and tools[0].diameter_m == 0.0


def test_a_table_file(tmp_path):
    path = tmp_path / "tool.tbl"
    path.write_text(TABLE, encoding="utf-8")
    assert read_tool_table(path) == parse_tool_table(TABLE, name=str(path))


def refusal(text: str) -> str:
    with pytest.raises(GcodeError) as caught:
        parse_tool_table(text, name="tool.tbl")
    message = str(caught.value)
    assert ONE_LINE.match(message), message
    return message


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("T1 P1 D3\nT1 P2 D4\n", "tool.tbl:2: T: tool 1 is already on line 1 (numbers are unique)"),
        ("P1 D3\n", "tool.tbl:1: T: missing: every tool line gives T and P (the tool number)"),
        ("T1 D3\n", "tool.tbl:1: P: missing: every tool line gives T and P (the pocket)"),
        ("T-1 P1\n", "tool.tbl:1: T: the tool number is a whole number 0 to 2147483647, got '-1'"),
        ("T1.5 P1\n", "tool.tbl:1: T: the tool number is a whole number 0 to 2147483647, got '1.5'"),
        ("T1 P\n", "tool.tbl:1: P: the pocket is a whole number 0 to 2147483647, got ''"),
        ("T1 P1 Q12\n", "tool.tbl:1: Q: the lathe orientation is a whole number 0 to 9, got '12'"),
        ("T1 P1 D3mm\n", "tool.tbl:1: D: the diameter is a number from -1000 to 1000 mm, got '3mm'"),
        ("T1 P1 D1e4\n", "tool.tbl:1: D: the diameter is a number from -1000 to 1000 mm, got '1e4'"),
        ("T1 P1 Dnan\n", "tool.tbl:1: D: the diameter is a number from -1000 to 1000 mm, got 'nan'"),
        ("T1 P1 D1_0\n", "tool.tbl:1: D: the diameter is a number from -1000 to 1000 mm, got '1_0'"),
        ("T1 P1 Zinf\n", "tool.tbl:1: Z: an offset (mm) is a finite number, got 'inf'"),
        ("T1 P1 I1,5\n", "tool.tbl:1: I: an angle (deg) is a finite number, got '1,5'"),
        ("T1 P1 D3 D4\n", "tool.tbl:1: D: given twice on the line"),
        ("T1 P1 H3\n", "tool.tbl:1: H3: unknown field; a tool line has T P X Y Z A B C U V W D I J Q and ;remark"),
        (
            "TOOLNO POCKET LENGTH DIAMETER\n",  # the format before LinuxCNC 2.4
            "tool.tbl:1: T: the tool number is a whole number 0 to 2147483647, got 'OOLNO'",
        ),
    ],
)
def test_each_refusal_names_the_line_the_field_and_the_range(text, message):
    assert refusal(text) == message


def test_the_diameter_range_is_inclusive():
    tools = parse_tool_table(f"T1 P1 D{DIAMETER_MAX_MM:g}\nT2 P2 D-{DIAMETER_MAX_MM:g}\n")
    assert tools[1].diameter_m == pytest.approx(1.0) and tools[2].diameter_m == pytest.approx(-1.0)
    assert refusal(f"T1 P1 D{DIAMETER_MAX_MM * 1.001:g}").startswith("tool.tbl:1: D:")


def test_a_file_that_is_not_a_table_is_one_line(tmp_path):
    for path, why in [
        (tmp_path / "missing.tbl", "no such file"),
        (tmp_path, "is a directory"),
        (os.devnull, "is not a regular file"),
    ]:
        with pytest.raises(GcodeError) as caught:
            read_tool_table(path)
        assert str(caught.value).startswith(f"{path}:0: file: {why}")
    big = tmp_path / "big.tbl"
    big.write_bytes(b"T1 P1 D3\n" * 40000)
    with pytest.raises(GcodeError, match="is larger than 256 KiB"):
        read_tool_table(big)
    latin = tmp_path / "latin.tbl"
    latin.write_bytes("T1 P1 D3 ;fräser\n".encode("latin-1"))
    with pytest.raises(GcodeError, match="not UTF-8 text"):
        read_tool_table(latin)


TOOLS = parse_tool_table("T1 P1 D3\nT2 P2 D6\nT5 P5 D4 Q2\n")


def test_the_tool_g41_uses():
    assert tool_for_compensation(TOOLS, 2, 1, file="p.ngc", line=3).number == 2  # D names it
    assert tool_for_compensation(TOOLS, None, 1, file="p.ngc", line=3).number == 1  # else the loaded one
    assert tool_for_compensation(TOOLS, 0, 1, file="p.ngc", line=3).number == 1  # D0: the loaded one


@pytest.mark.parametrize(
    ("d_word", "loaded", "message"),
    [
        (None, None, "p.ngc:3: G42: no tool: give D (a tool of the tool table) or load one with T.. M6"),
        (0, None, "p.ngc:3: G42: no tool: give D (a tool of the tool table) or load one with T.. M6"),
        (7, 1, "p.ngc:3: D: tool 7 is not in the tool table (the tool table has 1, 2, 5)"),
        (1.5, 1, "p.ngc:3: D: G42 takes a tool number, a whole number >= 0, got 1.5"),
        (-1, 1, "p.ngc:3: D: G42 takes a tool number, a whole number >= 0, got -1"),
        (None, 9, "p.ngc:3: G42: tool 9 is not in the tool table (the tool table has 1, 2, 5)"),
        (5, 1, "p.ngc:3: D: tool 5 is a lathe tool (Q2): no XZ plane here"),
    ],
)
def test_a_tool_g41_cannot_use_is_one_line(d_word, loaded, message):
    with pytest.raises(GcodeError) as caught:
        tool_for_compensation(TOOLS, d_word, loaded, file="p.ngc", line=3, code="G42")
    assert str(caught.value) == message


def test_without_a_table_the_message_says_how_to_give_one():
    with pytest.raises(GcodeError, match=r"no tool table was given \(--tool-table FILE\)"):
        tool_for_compensation({}, 1, None, file="p.ngc", line=3)
