"""LinuxCNC's dialect (docs/gcode.md): parameters, expressions, O-words, coordinate systems, planning words.

Each program is our own, written from LinuxCNC's documented semantics; each test checks the exact path
read (most only read, a few plan; nothing is simulated).
"""

from __future__ import annotations

import math
import re

import pytest

from gantry_twin.gcode import GcodeError, parse_program, read_program
from gantry_twin.gcode.planner import plan_program

ONE_LINE = re.compile(r"^[^\n:]+:\d+(?::\d+)?: [^\n:]+: [^\n]+$")


def path_mm(text: str, **kwargs) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """(start, end) of each move, mm, rounded to 1 nm."""
    program = parse_program(text, name="t.ngc", **kwargs)
    return [(_mm(m.start_m), _mm(m.end_m)) for m in program.moves]


def _mm(point) -> tuple[float, float]:
    return (round(float(point[0]) * 1e3, 6) + 0.0, round(float(point[1]) * 1e3, 6) + 0.0)


def x_values(exprs: list[str]) -> list[float]:
    """The X each expression moves to (one G1 per expression, Y stepping so no move is empty)."""
    text = "G1 F100\n" + "".join(f"X{e} Y{k + 1}\n" for k, e in enumerate(exprs))
    return [end[0] for _, end in path_mm(text)]


# -- parameters and expressions ----------------------------------------------------------------------------
EXPRESSIONS = {
    # precedence: ** before * / MOD before + - before comparisons before AND OR XOR; left to right within a level
    "[1+2*3]": 1 + 2 * 3,
    "[2*3**2]": 2 * 3**2,
    "[10-4-3]": (10 - 4) - 3,
    "[64/4/2]": (64 / 4) / 2,
    "[2**3**2]": (2**3) ** 2,  # left to right, not right-associative as in Python
    "[7 MOD 3+1]": (7 % 3) + 1,
    "[-7 MOD 3]": 2,  # the result takes the divisor's sign (LinuxCNC adds |b| to a negative fmod)
    "[1+2 EQ 3]": 1.0,  # + binds tighter than EQ
    "[3 EQ 3.00001]": 1.0,  # EQ within 0.0001
    "[3 NE 3.001]": 1.0,
    "[2 GT 1 AND 1 GT 2]": 0.0,
    "[1 OR 0 XOR 1]": 0.0,  # (1 OR 0) XOR 1
    "[[1 LE 1]+[2 GE 3]+[1 LT 2]]": 2.0,
    "[ABS[-2.5]]": 2.5,
    "[SIN[30]*10]": 10 * math.sin(math.radians(30)),
    "[COS[60]*10]": 10 * math.cos(math.radians(60)),
    "[TAN[45]*10]": 10 * math.tan(math.radians(45)),
    "[ASIN[0.5]]": math.degrees(math.asin(0.5)),
    "[ACOS[0.5]]": math.degrees(math.acos(0.5)),
    "[ATAN[1]/[-1]]": math.degrees(math.atan2(1, -1)),
    "[EXP[2]]": math.exp(2),
    "[LN[10]]": math.log(10),
    "[SQRT[2]*10]": math.sqrt(2) * 10,
    "[FIX[-1.5]]": -2.0,
    "[FUP[-1.5]]": -1.0,
    "[ROUND[2.5]]": 3.0,
    "[ROUND[-2.5]]": -3.0,
    "[[1+2]*3]": 9.0,
    "-[2+3]": -5.0,
    "[-SIN[90]]": -1.0,
}


def test_expressions_evaluate_as_documented():
    exprs = sorted(EXPRESSIONS)
    got = x_values(exprs)
    for expr, value in zip(exprs, got, strict=True):
        assert value == pytest.approx(EXPRESSIONS[expr], abs=1e-6), expr


def test_a_parameter_set_on_a_line_takes_effect_after_the_line():
    # #3 is 15; "#3=6 G1 X#3" moves to 15, and the next line sees 6 (LinuxCNC's overview, "Parameters").
    assert path_mm("#3=15\n#3=6 G1 X#3 F100\nY#3\n") == [((0, 0), (15, 0)), ((15, 0), (15, 6))]
    # two settings on one line both read the old values
    assert path_mm("#1=1 #2=2\n#1=#2 #2=#1\nG1 X#1 Y#2 F100\n") == [((0, 0), (2, 1))]


def test_numbered_named_and_indirect_parameters():
    text = "#<len>=4\n#<_w>=[#<len>/2]\n#7=3\n#8=7\nG1 X#<len> Y#<_w> F100\nX##8\nX#[7+1]\n"
    assert path_mm(text) == [((0, 0), (4, 2)), ((4, 2), (3, 2)), ((3, 2), (7, 2))]


def test_unset_numbered_parameters_read_zero_and_exists_tells_named_ones():
    assert path_mm("G1 X1 F100\nX#99 Y[EXISTS[#<a>]*5+EXISTS[#<_x>]]\n") == [((0, 0), (1, 0)), ((1, 0), (0, 1))]


def test_the_current_position_and_modes_read_back():
    text = "G20\nG1 X1 Y2 F10\nG21\nG1 X[#5420*10] Y[#<_y>+#<_metric>]\n"
    got = path_mm(text)
    assert got[1][1] == pytest.approx((254.0, 51.8))  # 25.4 mm * 10; 50.8 mm + 1 (G21: _metric 1)


def test_messages_are_kept_with_their_line_and_parameters_substituted():
    program = parse_program("#<a>=2\n(print, a is #<a>)\n(debug, #1)\n(msg, #<a> stays)\nG1 X1 F1\n", name="m.ngc")
    assert program.messages == ("m.ngc:2: print: a is 2.000000", "m.ngc:3: debug: 0.000000", "m.ngc:4: msg: #<a> stays")


# -- O-words -----------------------------------------------------------------------------------------------
POCKET = """o<pocket> sub
  G0 X#1 Y#2
  G1 X[#1+4] F600
  Y[#2+3]
  X#1
  Y#2
o<pocket> endsub
"""


def test_a_subroutine_called_in_a_loop_places_the_same_pocket_at_n_offsets():
    text = (
        POCKET + "#<k>=0\no1 while [#<k> LT 4]\n  o<pocket> call [#<k>*20-30] [-5]\n  #<k>=[#<k>+1]\no1 endwhile\nM2\n"
    )
    got = path_mm(text)
    square = [((0, 0), (4, 0)), ((4, 0), (4, 3)), ((4, 3), (0, 3)), ((0, 3), (0, 0))]
    expected = []
    for k in range(4):
        dx = k * 20 - 30
        if k:
            expected.append(((dx - 20, -5), (dx, -5)))  # the rapid to the next pocket
        expected += [((a[0] + dx, a[1] - 5), (b[0] + dx, b[1] - 5)) for a, b in square]
    assert got == expected


def test_call_arguments_and_locals_are_restored_and_globals_are_shared():
    text = """o<s> sub
  #<t>=[#1*10]
  #<_g>=#<t>
  #1=99
o<s> endsub
#<t>=1
#1=5
o<s> call [2]
G1 X#<t> Y#<_g> F100
X#1
"""
    assert path_mm(text) == [((0, 0), (1, 20)), ((1, 20), (5, 20))]


def test_return_values_and_branches():
    text = """o<half> sub
  o10 if [#1 LT 0]
    o<half> return [0]
  o10 endif
o<half> endsub [#1/2]
o<half> call [8]
G1 X#<_value> F100
o<half> call [-8]
Y[#<_value>+1]
#1=3
o20 if [#1 EQ 1]
  X1
o20 elseif [#1 EQ 3]
  X3
o20 elseif [#1 GT 2]
  X30
o20 else
  X99
o20 endif
"""
    assert path_mm(text) == [((0, 0), (4, 0)), ((4, 0), (4, 1)), ((4, 1), (3, 1))]


def test_loops_break_and_continue():
    text = """G91 G1 F100
#1=0
o1 do
  #1=[#1+1]
  o2 if [#1 EQ 2]
    o1 continue
  o2 endif
  o3 if [#1 EQ 5]
    o1 break
  o3 endif
  X#1
o1 while [#1 LT 10]
o4 repeat [3]
  Y1
o4 endrepeat
o5 repeat [0]
  Y100
o5 endrepeat
"""
    ends = [end for _, end in path_mm(text)]
    assert ends == [(1, 0), (4, 0), (8, 0), (8, 1), (8, 2), (8, 3)]


def test_subroutines_in_other_files_are_found_on_the_path_then_beside_the_program(tmp_path):
    lib, own = tmp_path / "lib", tmp_path / "prog"
    lib.mkdir()
    own.mkdir()
    (lib / "step.ngc").write_text("o<step> sub\nG91 G1 X#1 F100\nG90\no<step> endsub\n")
    (own / "step.ngc").write_text("o<step> sub\nG91 G1 Y#1 F100\nG90\no<step> endsub\n")
    (own / "main.ngc").write_text("o<step> call [2]\no<step> call [3]\nM2\n")
    ends = [m.end_m for m in read_program(own / "main.ngc", subroutine_path=(lib,)).moves]
    assert [_mm(e) for e in ends] == [(2, 0), (5, 0)]
    ends = [m.end_m for m in read_program(own / "main.ngc").moves]
    assert [_mm(e) for e in ends] == [(0, 2), (0, 5)]
    (own / "main.ngc").write_text("o<nowhere> call\n")
    with pytest.raises(GcodeError, match=rf"main.ngc:1:1: o<nowhere> call: no such subroutine \(searched: this "
                       rf"file, {re.escape(str(lib))}, {re.escape(str(own))}\)"):  # fmt: skip
        read_program(own / "main.ngc", subroutine_path=(lib,))


def test_m70_to_m73_save_and_restore_the_modal_state():
    text = """o<inch> sub
  M73
  G20 G91
o<inch> endsub
G21 G90 G1 F100
o<inch> call
X1
M70
G20
X1
M72
X2
"""
    # after the call: G21 G90 again (M73); X1 is 1 mm; M72 restores G21 after the G20 move to 25.4 mm
    ends = [end for _, end in path_mm(text)]
    assert ends == [(1, 0), (25.4, 0), (2, 0)]


def test_an_endless_loop_stops_at_the_block_bound_with_its_line():
    # block 1 is line 1, then 4 blocks a turn (lines 2-5): block 1001 is line 5, the 250th endwhile
    with pytest.raises(GcodeError, match=r"^t.ngc:5: program: more than 1000 blocks executed"):
        parse_program("G1 F100\no1 while [1]\n  X1\n  X0\no1 endwhile\n", name="t.ngc", max_blocks=1000)


def test_endless_recursion_stops_at_linuxcnc_s_nine_levels():
    text = "o<r> sub\n#<_n>=[#<_n>+1]\no<r> call\no<r> endsub\n#<_n>=0\no<r> call\n"
    with pytest.raises(GcodeError, match=r"^t.ngc:3:1: o<r> call: calls nested deeper than 9 levels"):
        parse_program(text, name="t.ngc")
    # nine levels are allowed
    deep = "o<r> sub\no1 if [#1 GT 0]\no<r> call [#1-1]\no1 endif\no<r> endsub\no<r> call [8]\nG1 X1 F1\n"
    assert path_mm(deep) == [((0, 0), (1, 0))]
    with pytest.raises(GcodeError, match=r"^t.ngc:3:1: o<r> call: calls nested deeper than 9 levels"):
        parse_program(deep.replace("call [8]", "call [9]"), name="t.ngc")  # a tenth level


# -- coordinate systems ------------------------------------------------------------------------------------
def test_g10_l20_then_g55_shifts_the_path_by_the_given_amounts():
    square = "G1 X0 Y0 F300\nX10\nY10\nX0\nY0\n"
    base = path_mm("G0 X30 Y-20\n" + square)
    shifted = path_mm("G0 X30 Y-20\nG10 L20 P2 X-5 Y7\nG55\n" + square)
    # L20: at machine (30, -20) G55's coordinates become (-5, 7): its origin is at (35, -27)
    assert shifted[0] == ((30, -20), (35, -27))
    assert shifted[1:] == [((a[0] + 35, a[1] - 27), (b[0] + 35, b[1] - 27)) for a, b in base[1:]]


def test_g10_l2_sets_a_system_and_g54_to_g59_3_select_it():
    text = "G10 L2 P1 X1 Y2\nG10 L2 P9 X-100 Y50\nG1 X0 Y0 F100\nG59.3 X0 Y0\nG54 X3\n"
    assert path_mm(text) == [((0, 0), (1, 2)), ((1, 2), (-100, 50)), ((-100, 50), (4, 50))]
    # parameters 5221.. hold the offsets (G59.3's at 5221 + 8 * 20)
    assert path_mm("G10 L2 P9 X-100 Y50\nG1 X#5381 Y#5382 F100\n") == [((0, 0), (-100, 50))]


def test_the_g92_family():
    text = """G10 L2 P1 X10 Y0
G1 X5 Y0 F100
G92 X0 Y0
X1
G92.2
X1
G92.3
X2
G92.1
X0
"""
    # G92 makes machine 15 the point 0: X1 -> 16; G92.2 suspends it: X1 -> 11; G92.3 restores: X2 -> 17;
    # G92.1 clears it: X0 -> 10
    ends = [end[0] for _, end in path_mm(text)]
    assert ends == [15, 16, 11, 17, 10]


def test_g53_moves_in_machine_coordinates_for_its_line():
    text = "G10 L2 P1 X10 Y10\nG1 X0 Y0 F100\nG53 G1 X0 Y0\nX1\n"
    assert path_mm(text) == [((0, 0), (10, 10)), ((10, 10), (0, 0)), ((0, 0), (11, 0))]


def test_initial_work_offsets_and_polar_coordinates():
    # G91 polar is about the XY zero too: @5 lengthens the radius 10 to 15 (LinuxCNC's find_ends)
    text = "G1 @10 ^90 F100\nG91 @5 ^0\nG90 G55 @2 ^180\n"
    got = path_mm(text, work_offsets_mm={1: (1.0, 2.0), 2: (-50.0, 0.0)})
    assert got == [((0, 0), (1, 12)), ((1, 12), (1, 17)), ((1, 17), (-52, 0))]


# -- planning words ----------------------------------------------------------------------------------------
WIGGLE = (
    "G0 X0 Y0\nG64 P0.01 Q0.002\nG1 F600\n"
    + "".join(f"X{k} Y{0.001 if k % 2 else -0.001}\n" for k in range(1, 40))
    + "X40 Y0\nX40 Y10\n"
)


def test_g64_q_merges_a_wiggling_polyline_into_one_move():
    program = parse_program(WIGGLE, name="w.ngc")
    assert [(_mm(m.start_m), _mm(m.end_m)) for m in program.moves] == [((0, 0), (40, 0)), ((40, 0), (40, 10))]
    assert program.merged == 39 and len(program.programmed_moves) == 41
    unmerged = parse_program(WIGGLE.replace("Q0.002", "Q0"), name="w.ngc")
    assert len(unmerged.moves) == 41 and unmerged.merged == 0
    # a wiggle larger than Q stays
    assert len(parse_program(WIGGLE.replace("Q0.002", "Q0.0005"), name="w.ngc").moves) == 41


def test_g64_q_defaults_to_p_and_g61_stops_merging():
    assert parse_program(WIGGLE.replace(" Q0.002", ""), name="w.ngc").merged == 39
    assert parse_program(WIGGLE.replace("G64 P0.01 Q0.002", "G61"), name="w.ngc").merged == 0


def test_g64_p0_blends_without_a_tolerance_as_g64_alone():
    moves = parse_program("G64 P0\nG1 X10 F600\nY10\n", name="t.ngc").moves
    assert [m.tolerance_m for m in moves] == [math.inf, math.inf] and not moves[0].exact_stop


def test_block_delete_is_on_by_default_and_switchable():
    text = "G1 X1 F100\n/G1 X5\nX2\n"
    assert [e for _, e in path_mm(text)] == [(1, 0), (2, 0)]
    assert [e for _, e in path_mm(text, block_delete=False)] == [(1, 0), (5, 0), (2, 0)]


def test_drilling_cycles_move_between_holes_and_drop_their_z_part():
    text = "G0 X0 Y0 Z5\nG91 G81 X10 Y5 Z-2 R1 L3 F100\nG90 G82 X-20 Y0 Z-1 R1 P0.5\nX-30\nG80\nG1 X0 F100\n"
    program = parse_program(text, name="d.ngc", drop_unsupported=True)
    assert [(_mm(m.start_m), _mm(m.end_m), m.rapid) for m in program.moves] == [
        ((0, 0), (10, 5), True), ((10, 5), (20, 10), True), ((20, 10), (30, 15), True),
        ((30, 15), (-20, 0), True), ((-20, 0), (-30, 0), True), ((-30, 0), (0, 0), False),
    ]  # fmt: skip
    assert program.dropped == {"Z axis": 1, "drilling cycle (its Z motion)": 5}
    with pytest.raises(GcodeError, match=r"d.ngc:2:5: G81: drilling cycle \(its Z motion\): a two-axis gantry"):
        parse_program(text.replace("Z5", ""), name="d.ngc")


def test_a_merged_program_plans():
    plan = plan_program(parse_program(WIGGLE, name="w.ngc"))
    assert len(plan.moves) == 2


# -- cutter compensation's words (the geometry is connected in machine.compensated_run) ---------------------
def test_compensation_words_are_checked_and_the_programmed_path_kept():
    with pytest.raises(GcodeError, match=r"^t.ngc:1:1: G41: no tool: select one"):
        parse_program("G41 G1 X1 F10\n", name="t.ngc")
    with pytest.raises(GcodeError, match=r"^t.ngc:3:1: G42: cutter compensation is already on"):
        parse_program("T1 M6\nG41 G1 X1 F10\nG42 X2\n", name="t.ngc")
    with pytest.raises(GcodeError, match=r"^t.ngc:2: G41: tool 3 is not in the tool table \(no tool table was given"):
        parse_program("T3 M6\nG41 G1 X1 F10\nX2\nG40 X3\n", name="t.ngc")
    with pytest.raises(GcodeError, match=r"^t.ngc:1:1: G42.1: needs D"):
        parse_program("G42.1 G1 X1 F10\n", name="t.ngc")


@pytest.mark.parametrize(
    ("text", "where", "message"),
    [
        ("G1 X[1+2 F10\n", "1:5", "[: expression not closed with ]"),
        ("G1 X[FOO[2]] F10\n", "1:6", "FOO: unknown function"),
        ("G1 X1 F10\no7 endwhile\n", "2:1", "o7 endwhile: endwhile without o7 while"),
        ("o7 while [1]\nG1 X1 F1\n", "1:1", "o7 while: not closed (no o7 endwhile)"),
        ("o<gone> call\n", "1:1", "o<gone> call: no such subroutine (searched: this file"),
        ("G1 X[1/0] F10\n", "1:7", "/: division by zero"),
        ("G1 X#<nope> F10\n", "1:5", "#<nope>: named parameter not defined"),
        ("G1 X[SQRT[-1]] F10\n", "1:6", "SQRT: needs a value >= 0"),
        ("#6000=1\n", "1:1", "#6000: cannot be set"),
        ("#<_x>=1\n", "1:1", "#<_x>: a read-only parameter"),
        ("o1 if [1]\no1 else\no1 elseif [1]\no1 endif\n", "3:1", "o1 elseif: elseif after o1 else"),
        ("o1 break\n", "1:1", "o1 break: break outside a loop labelled o1"),
        ("o1 frobnicate\n", "1:4", "unknown O-word keyword"),
        ("G1 X1 F1 o1 call\n", "1:10", "O: an O-word must begin its line"),
        ("G1 @1 X1 F1\n", "1:4", "@: polar (@ ^) and X Y on one line"),
        ("G10 L2 P12 X1\n", "1:8", "P: G10 needs P0-P9"),
        ("G53 G91 G1 X1 F1\n", "1:1", "G53: machine coordinates need G90"),
        ("G33 X1\n", "1:1", "G33: spindle-synchronised motion"),
        ("G76 X1\n", "1:1", "G76: spindle-synchronised motion"),
        ("G7\n", "1:1", "G7: lathe diameter mode"),
        ("M72\n", "1:1", "M72: no modal state saved"),
        ("G1 X#<a F1\n", "1:5", "#<: named parameter not closed"),
        ("G1 X[ATAN[1]] F1\n", "1:13", "ATAN: takes two arguments"),
    ],
)
def test_malformed_constructs_are_one_line_with_the_column(text, where, message):
    with pytest.raises(GcodeError) as info:
        parse_program(text, name="bad.ngc")
    shown = str(info.value)
    assert ONE_LINE.match(shown), shown
    assert shown.startswith(f"bad.ngc:{where}: ") and message in shown, shown


def test_forms_linuxcnc_s_own_test_programs_use():
    # G80 beside a motion code on one line (the motion code wins); G53 / G92 with only a dropped axis;
    # F0 before a feed; a cycle's R not taken from an arc's line; a return labelled by the if it is in.
    text = "G90 G17 G40 G80 G00 G20\nX1\nG0 G53 Z-10\nG92 A5\nF0\nG21 G1 X0 F100\n"
    assert path_mm(text, drop_unsupported=True) == [((25.4, 0), (0, 0))]
    arc = "G0 X0 Y0\nG81 X1 Y0 Z-1 R1\nG2 X2 Y0 R0.5 F100\n"
    assert len(parse_program(arc, name="t.ngc", drop_unsupported=True).moves) == 2
    sub = "o<s> sub\no9 if [1]\no9 return [3]\no9 endif\no<s> endsub\no<s> call\nG1 X#<_value> F100\n"
    assert path_mm(sub) == [((0, 0), (3, 0))]
    with pytest.raises(GcodeError, match=r"t.ngc:1:1: G1: no feed: F is 0"):
        parse_program("G1 X1 F0\n", name="t.ngc")


def test_a_rotated_system_turns_lines_arcs_and_increments_about_its_origin():
    # G10 L2 R90: program X is machine Y; machine = offset + rotated (program + G92), as LinuxCNC's canon
    text = "G10 L2 P1 X10 Y0 R90\nG1 X1 Y0 F100\nG91 X1\nG90 G3 X4 Y0 I1 J0\nG1 X[#5420+1]\n"
    program = parse_program(text, name="r.ngc")
    ends = [_mm(m.end_m) for m in program.moves]
    assert ends == [(10, 1), (10, 2), (10, 4), (10, 5)]
    arc = program.moves[2]
    assert _mm(arc.centre_m) == (10, 3) and arc.sweep_rad == pytest.approx(math.pi)  # a half turn, ccw kept
    # G10 L20 in a rotated system: the current point becomes the given program point
    assert path_mm("G10 L2 P1 R90\nG10 L20 P1 X0 Y0\nG1 X1 F100\n") == [((0, 0), (0, 1))]
    # G92 in a rotated system: offsets the program point before the rotation
    assert path_mm("G10 L2 P1 R90\nG1 X1 F100\nG92 X0\nG1 X2\n") == [((0, 0), (0, 1)), ((0, 1), (0, 3))]


def test_a_subroutine_file_s_errors_name_that_file(tmp_path):
    (tmp_path / "wide.ngc").write_text("o<wide> sub\nG1 X300 F100\no<wide> endsub\n")
    (tmp_path / "main.ngc").write_text("G1 X1 F100\no<wide> call\n")
    with pytest.raises(GcodeError, match=rf"^{re.escape(str(tmp_path / 'wide.ngc'))}:2: X: the move reaches 300 mm"):
        read_program(tmp_path / "main.ngc")


def test_g28_and_g30_go_home_through_the_given_point():
    text = "G1 X20 Y10 F100\nG30.1\nG1 X0 Y0\nG28 X5\nG1 Y3\nG30\nG91 G28 Z0\nG90 G28\n"
    got = path_mm(text, drop_unsupported=True)
    # G28 X5: a rapid to X5, then X (only) to G28's position, machine 0 (unset); G30: both axes to (20, 10);
    # G28 Z0: only Z (dropped) goes home; G28 alone: both axes to machine (0, 0)
    assert got == [
        ((0, 0), (20, 10)), ((20, 10), (0, 0)), ((0, 0), (5, 0)), ((5, 0), (0, 0)), ((0, 0), (0, 3)),
        ((0, 3), (20, 10)), ((20, 10), (0, 0)),
    ]  # fmt: skip
