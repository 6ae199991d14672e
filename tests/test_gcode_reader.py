"""The G-code reader (gantry_twin.gcode.reader): what it reads, and one precise message for each thing it refuses."""

from __future__ import annotations

import math
import os
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gantry_twin.gcode import GcodeError, parse_program, read_program
from gantry_twin.gcode.geometry import MoveTable
from gantry_twin.gcode.planner import plan_program
from gantry_twin.gcode.reader import MAX_FILE_BYTES

#: FILE:LINE: WORD: what is wrong
ONE_LINE = re.compile(r"^[^\n:]+:\d+(?::\d+)?: [^\n:]+: [^\n]+$")


def moves(text: str, **kwargs):
    return parse_program(text, name="t.ngc", **kwargs).moves


def test_lines_arcs_units_and_modes():
    program = parse_program(
        "%\nG21 G90 G17 (set up)\nG0 X10 Y-20 ; start\nG1 X20 F6000\nY-10\nG91 G1 X5 Y5\nG90 G3 X35 Y-5 R10\n"
        "G20 G1 X0 Y0\nM30\n%\nG1 X100\n",
        name="t.ngc",
    )
    assert program.start_m == pytest.approx((0.010, -0.020))
    kinds = [m.kind for m in program.moves]
    assert kinds == ["line", "line", "line", "arc", "line"]
    first = program.moves[0]
    assert first.end_m == pytest.approx((0.020, -0.020)) and first.feed_m_s == pytest.approx(0.1)
    assert program.moves[2].end_m == pytest.approx((0.025, -0.005))
    arc = program.moves[3]
    assert arc.sweep_rad > 0 and arc.radius_m == pytest.approx(0.010)
    assert arc.end_m == pytest.approx((0.035, -0.005))
    assert program.moves[4].feed_m_s == pytest.approx(0.1)  # G20 keeps the feed speed (LinuxCNC converts F)


def test_a_full_circle_and_turns():
    (arc,) = moves("G0 X0 Y-200\nG2 X0 Y-200 I0 J200 P2 F24000\n")
    assert arc.sweep_rad == pytest.approx(-4 * math.pi)
    assert arc.length_m == pytest.approx(0.8 * math.pi)
    (ccw,) = moves("G0 X10 Y0\nG3 I-10 J0 F100\n")
    assert ccw.sweep_rad == pytest.approx(2 * math.pi) and ccw.centre_m == pytest.approx((0.0, 0.0))


@pytest.mark.parametrize(("r", "sweep"), [(10.0, 0.5 * math.pi), (-10.0, 1.5 * math.pi)])
def test_an_arc_by_its_radius(r, sweep):
    (arc,) = moves(f"G0 X10 Y0\nG3 X0 Y10 R{r} F100\n")
    assert arc.sweep_rad == pytest.approx(sweep)
    assert np.hypot(*np.subtract(arc.end_m, arc.centre_m)) == pytest.approx(0.010)


def test_an_arc_end_within_linuxcnc_tolerance_ends_at_the_programmed_point_along_linuxcncs_spiral():
    pieces = moves("G0 X10 Y0\nG3 X0 Y10.02 I-10 J0 F100\n")  # 0.02 mm off: within 0.028 mm
    assert pieces[-1].end_m == (0.0, 0.01002)  # the programmed end, as LinuxCNC keeps it
    assert [p.piece for p in pieces] == [False]  # a quarter turn: one arc, through both ends
    # The path stays within 1 um of LinuxCNC's spiral, radius 10 + 0.02 * angle / (pi / 2) mm about (0, 0).
    table = MoveTable(pieces)
    for k, piece in enumerate(pieces):
        sweep = abs(piece.sweep_rad)
        u = np.linspace(0.0, piece.length_m, 50)
        p = table.kinematics(np.full(50, k), u, u * 0, u * 0, u * 0)[0]
        angle = np.arctan2(p[:, 1], p[:, 0])
        spiral = 0.010 + 0.00002 * angle / (0.5 * math.pi)
        assert np.abs(np.hypot(p[:, 0], p[:, 1]) - spiral).max() < 1e-6, sweep


def test_a_full_circle_off_its_end_is_cut_in_quarter_turns_ending_at_the_programmed_point():
    pieces = moves("G0 X10 Y0\nG2 X10.01 Y0 I-10 J0 P2 F100\n")  # two turns, 10 um outwards
    assert [p.piece for p in pieces] == [True] * 7 + [False]
    assert pieces[-1].end_m == (0.01001, 0.0)
    assert sum(p.sweep_rad for p in pieces) == pytest.approx(-4.0 * math.pi, abs=1e-6)
    for a, b in zip(pieces[:-1], pieces[1:], strict=True):
        assert a.end_m == b.start_m


def test_utf8_in_comments_is_read_as_linuxcnc_keeps_it():
    program = parse_program("G1 X1 F10 (caf\u00e9 \u00b0C) ; \u00fc\n(msg, r\u00e9sum\u00e9)\n")
    assert program.moves[0].end_m == (0.001, 0.0)
    assert program.messages == ("<program>:2: msg: r?sum?",)


def test_dropped_words_are_counted():
    program = parse_program("G0 X0 Y0 Z5\nM3 S1000\nG1 X10 Z-1 F100\nT1 M6\nM8\nM30", drop_unsupported=True)
    assert program.dropped == {"Z axis": 2, "spindle": 1, "coolant": 1}  # T M6 select a tool; S is read (G95)
    assert [m.end_m for m in program.moves] == [pytest.approx((0.010, 0.0))]


#: Malformed or unsupported programs, each with the line and the words its message must have.
BAD = {
    "unknown G": ("G1 X1 F10\nG6 X2\n", 2, "G6: unsupported G code"),
    "unknown M": ("M99\n", 1, "M99: unsupported M code"),
    "G code not whole": ("G1.55 X1\n", 1, "G1.55: unknown G code"),
    "arc end off circle": ("G0 X10 Y0\nG3 X0 Y11 I-10 J0 F100\n", 2, "G3: the end is not on the arc's circle"),
    "G2 without centre": ("G0 X10 Y0\nG2 X0 Y10 F100\n", 2, "G2: an arc needs its centre"),
    "I J and R": ("G2 X1 Y1 I1 R1 F100\n", 1, "R: an arc takes I J or R, not both"),
    "R too small": ("G2 X100 Y0 R10 F100\n", 1, "R: radius too small"),
    "full circle by R": ("G0 X10 Y0\nG2 X10 Y0 R5 F100\n", 2, "R: a full circle needs I J"),
    "zero radius": ("G0 X10 Y0\nG2 X0 Y0 I-10 J0 F100\n", 2, "zero-radius arc"),
    "no F": ("G0 X1\nG1 X2\n", 2, "G1: no feed"),
    "F zero": ("G1 X1 F0\n", 1, "G1: no feed: F is 0"),
    "F negative": ("G1 X1 F-1\n", 1, "F: the feed must be >= 0"),
    "G18": ("G18\n", 1, "G18: only the XY plane"),
    "G19": ("G19 G1 X1 F1\n", 1, "G19: only the XY plane"),
    "Z move": ("G1 X1 Z-1 F100\n", 1, "Z: Z axis: a two-axis gantry cannot do this"),
    "A axis": ("G0 A90\n", 1, "A: A axis"),
    "spindle": ("M3 S1000\n", 1, "M3: spindle"),
    "spindle speed": ("S-1\n", 1, "S: the spindle speed must be >= 0"),
    "coolant": ("M8\n", 1, "M8: coolant"),
    "K word": ("G2 X1 Y0 I0.5 K1 F10\n", 1, "K: not used in the XY plane"),
    "leaving the travel": ("G1 X300 F100\n", 1, "X: the move reaches 300 mm, outside the travel"),
    "arc leaving the travel": ("G0 X200 Y0\nG3 X200 Y0 I40 J0 F100\n", 2, "X: the move reaches 280 mm"),
    "two motion codes": ("G0 G1 X1\n", 1, "G1: a second motion code"),
    "word repeated": ("G1 X1 X2 F10\n", 1, "X: word repeated"),
    "G4 without P": ("G4\n", 1, "G4: a dwell needs P"),
    "negative dwell": ("G4 P-1\n", 1, "P: a dwell cannot be negative"),
    "G64 P negative": ("G64 P-1\n", 1, "P: the G64 tolerance must be >= 0"),
    "stray P": ("G1 X1 P3 F10\n", 1, "P: P only follows G4, G64, G10 or an arc"),
    "unclosed comment": ("G1 X1 (oops\n", 1, "(: comment not closed"),
    "nested comment": ("(a (b) c)\n", 1, "(: nested comment"),
    "stray parenthesis": ("G1 X1 F1)\n", 1, "): closing parenthesis"),
    "parameter alone": ("#1\n", 1, "#: a parameter on its own"),
    "unclosed bracket": ("G1 F1 X[1+2\n", 1, "[: expression not closed"),
    "letter without number": ("G1 X F10\n", 1, "X: a number must follow"),
    "not a word": ("G1 X1 F10\n123\n", 2, "line: expected a word (a letter and a number) at '123'"),
    "binary junk": (b"G1 X1 F10\n\x00\xff\x13binary\n", 2, "line: byte 0x00 at column 1"),
    "non-ascii": ("G1 X1 F10 Y\u00e9\n", 1, "line: '\u00e9' at column 12: not ASCII, and not in a comment"),
    "not utf-8": (b"G1 X1 F10 (caf\xe9)\n", 1, "line: byte 0xe9 at column 15: not G-code text"),
    "axis word without motion": ("X10\n", 1, "X: an axis word without G0"),
    "I on a line": ("G1 X1 I2 F10\n", 1, "I: only arcs take it"),
    "negative line number": ("N-5 G1 X1 F1\n", 1, "N: a line number is a whole number"),
    "unknown letter": ("G1 X1 F10 E3\n", 1, "E: unsupported word"),
    "arc turns": ("G0 X10 Y0\nG3 I-10 J0 P1.5 F100\n", 2, "P: arc turns must be a whole number"),
    "no moves": ("G21 G90\nM30\n", 0, "program: has no moves to run"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_each_bad_program_has_its_own_one_line_message(case):
    text, line, message = BAD[case]
    with pytest.raises(GcodeError) as info:
        program = parse_program(text, name="bad.ngc")
        plan_program(program)
    text_of = str(info.value)
    assert ONE_LINE.match(text_of), text_of
    assert re.match(rf"bad.ngc:{line}(:\d+)?: ", text_of) and message in text_of, text_of


def test_the_messages_are_all_different():
    messages = set()
    for text, _, _ in BAD.values():
        try:
            plan_program(parse_program(text, name="bad.ngc"))
        except GcodeError as error:
            messages.add(str(error))
    assert len(messages) == len(BAD) >= 30


def test_a_file_over_the_cap_is_refused_before_it_is_read(tmp_path):
    big = tmp_path / "big.ngc"
    with open(big, "wb") as handle:
        handle.truncate(100 * 1024 * 1024)  # 100 MB, sparse: nothing is written to disk
    with pytest.raises(GcodeError, match=rf"big.ngc:0: file: is {100 * 1024 * 1024} bytes, more than the"):
        read_program(big)
    assert os.path.getsize(big) > MAX_FILE_BYTES


def test_a_line_of_10_mb_is_refused(tmp_path):
    path = tmp_path / "long.ngc"
    path.write_bytes(b"G1 X1 F10\n(" + b"a" * (10 * 1024 * 1024) + b")\n")
    with pytest.raises(GcodeError, match=r"long.ngc:2: line: longer than 256 characters"):
        read_program(path)


def test_only_regular_files_are_read(tmp_path):
    with pytest.raises(GcodeError, match=r":0: file: is not a regular file"):
        read_program(tmp_path)
    fifo = tmp_path / "pipe.ngc"
    os.mkfifo(fifo)
    with pytest.raises(GcodeError, match=r"pipe.ngc:0: file: is not a regular file"):
        read_program(fifo)  # would block forever if opened
    with pytest.raises(GcodeError, match=r"missing.ngc:0: file: cannot be read"):
        read_program(tmp_path / "missing.ngc")


def test_the_shipped_programs_read(programs_dir=None):
    from pathlib import Path

    for path in sorted((Path(__file__).resolve().parents[1] / "programs").glob("*.ngc")):
        program = read_program(path)
        assert program.moves, path
        assert "(" in path.read_text().splitlines()[1], f"{path.name}: says what it exercises"


GCODE_ALPHABET = "GMXYIJRFNPSTZK0123456789.-+ ()%;\n#[]/"


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.binary(max_size=400), st.text(alphabet=GCODE_ALPHABET, max_size=400)))
def test_any_input_is_a_program_or_one_gcode_error(data):
    try:
        program = parse_program(data, name="fuzz.ngc")
    except GcodeError as error:
        assert ONE_LINE.match(str(error)), str(error)
        return
    if program.moves:
        try:
            plan_program(program)
        except GcodeError as error:
            assert ONE_LINE.match(str(error))


def test_huge_numbers_are_refused():
    with pytest.raises(GcodeError, match=r"t.ngc:1: X: the move reaches 1e\+2\d\d mm, outside the travel"):
        parse_program("G1 X" + "9" * 240 + " F10", name="t.ngc")
    with pytest.raises(GcodeError, match=r"t.ngc:1:1: G1e\+250: unknown G code$"):
        parse_program("G" + "9" * 250, name="t.ngc")
