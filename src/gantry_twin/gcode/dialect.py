"""The dialect's table: every word and construct with its status, and a program that shows it.

docs/gcode.md's dialect section is :func:`dialect_table`; tests/test_gcode_dialect_doc.py runs each
entry's example through the reader (read: no error; dropped: refused without ``drop_unsupported``
and counted with it; refused: the error names the reason) and checks that the table lists every code
the machine reads or refuses, so the table cannot disagree with the reader.
"""

from __future__ import annotations

from typing import NamedTuple

#: The tool table the examples read with (G41 / G42 D1 and T1 M6 name its tool 1): LinuxCNC's format.
EXAMPLE_TOOLS = "T1 P1 D3.0 ;a 3 mm end mill\n"


class Entry(NamedTuple):
    word: str  # the code, letter or construct, as the table shows it
    status: str  # "read", "dropped" or "refused"
    what: str  # what it does here, or why it is refused (a part of the reader's message)
    example: str  # a short program that uses it


_F = "G1 X1 F100\n"
DIALECT: tuple[Entry, ...] = (
    Entry("G0", "read", "rapid move", "G0 X1\nG0 X2\n"),
    Entry("G1", "read", "line at the feed F", _F),
    Entry("G2", "read", "clockwise arc: centre I J (from the start) or radius R; P turns", "G2 X2 I1 F100\n"),
    Entry("G3", "read", "counter-clockwise arc, as G2", "G3 X2 R1 F100\n"),
    Entry("G4", "read", "dwell P seconds", "G4 P0.5\n" + _F),
    Entry(
        "G5",
        "read",
        "cubic spline to X Y: control points start + I J (left out: the last G5's -P -Q) and end + P Q; "
        "sampled into arcs as LinuxCNC's canon",
        "G5 X10 Y0 I2 J3 P-2 Q3 F100\nG5 X20 Y0 P-2 Q-3\n",
    ),  # fmt: skip
    Entry("G5.1", "read", "quadratic spline to X Y, control point start + I J; sampled as G5", "G5.1 X10 I5 J5 F100\n"),
    Entry(
        "G5.2",
        "read",
        "NURBS: control points X Y of weight P (the current point the first), order L (at least 3); sampled as G5",
        "G5.2 X0 Y5 P1 L3 F100\nX5 Y5 P2\nX5 Y0 P1\nG5.3\n",
    ),  # fmt: skip
    Entry("G5.3", "read", "end the NURBS (G5.2) and move along it", "G5.2 X0 Y5 P1 F100\nX5 Y5 P1\nG5.3\n"),
    Entry("G7", "refused", "lathe diameter mode", "G7\n"),
    Entry("G8", "read", "lathe radius mode (the start, a mill's): nothing to do", "G8\n" + _F),
    Entry(
        "G10",
        "read",
        "L2 P X Y R: a system's offset and rotation (degrees); L20 P X Y: the offset making the current point X Y; "
        "L1 / L10 / L11 P R Q: tool P's radius and orientation in the tool table (its offsets read, not used)",
        "G10 L2 P2 X1 Y1 R30\nG10 L20 P0 X5\nG10 L1 P3 R1.5\n" + _F,
    ),  # fmt: skip
    Entry("G17", "read", "the XY plane (the only one)", "G17\n" + _F),
    Entry("G18", "refused", "only the XY plane (G17)", "G18\n"),
    Entry("G19", "refused", "only the XY plane (G17)", "G19\n"),
    Entry("G20", "read", "inches", "G20\n" + _F),
    Entry("G21", "read", "millimetres (the start)", "G21\n" + _F),
    Entry(
        "G28",
        "read",
        "rapid through the X Y given to the stored position (5161-5162, mm; both axes if none given)",
        "G28.1\nG1 X5 F100\nG28 X1\n",
    ),  # fmt: skip
    Entry("G28.1", "read", "store the current point for G28", "G28.1\n" + _F),
    Entry("G30", "read", "as G28 with the position 5181-5182", "G30\n" + _F),
    Entry("G30.1", "read", "store the current point for G30", "G30.1\n" + _F),
    Entry("G33", "refused", "spindle-synchronised motion", "G33 X1\n"),
    Entry("G33.1", "refused", "spindle-synchronised motion", "G33.1 X1\n"),
    Entry("G40", "read", "cutter compensation off (after the next move)", "G40\n" + _F),
    Entry(
        "G41",
        "read",
        "cutter radius compensation, tool left of the path: D a tool of the tool table (or the one M6 selected)",
        "T1 M6\nG41 G1 X5 F100\nX10\nG40 X15\n",
    ),  # fmt: skip
    Entry("G41.1", "read", "as G41, D the tool's diameter", "G41.1 D3 G1 X5 F100\nX10\nG40 X15\n"),
    Entry("G42", "read", "cutter radius compensation, tool right of the path (as G41)", "G42 D1 G1 X5 F100\nG40 X10\n"),
    Entry("G42.1", "read", "as G42, D the tool's diameter", "G42.1 D3 G1 X5 F100\nG40 X10\n"),
    Entry("G43", "dropped", "tool length offset", "G43 H1\n" + _F),
    Entry("G49", "read", "tool length offset off: nothing to do", "G49\n" + _F),
    Entry("G53", "read", "machine coordinates for its line (G0 / G1, G90)", "G10 L2 P1 X5\nG53 G1 X1 F100\n"),
    *(
        Entry(code, "read", f"work coordinate system {n} (offsets from G10 or the scenario)", f"{code}\n" + _F)
        for n, code in enumerate(("G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3"), 1)
    ),
    Entry("G61", "read", "exact path: stop at every corner", "G61\n" + _F),
    Entry("G61.1", "read", "exact stop: as G61", "G61.1\n" + _F),
    Entry(
        "G64",
        "read",
        "blend; P tolerance (P0: none, as G64 alone); Q merges G1 lines within Q (default P)",
        "G64 P0.01 Q0.001\n" + _F,
    ),  # fmt: skip
    Entry("G76", "refused", "spindle-synchronised motion (threading)", "G76 P1\n"),
    Entry("G80", "read", "cancel a drilling cycle", "G80\n" + _F),
    *(
        Entry(
            f"G{n}",
            "dropped",
            "drilling cycle (its Z motion); the rapid to each X Y is a move, L repeats in G91",
            f"G0 X0 Y0\nG{n} X5 Y5 Z-1 R1{' P0.5' if n in (82, 89) else ''}\n",
        )  # fmt: skip
        for n in range(81, 90)
    ),
    Entry("G90", "read", "absolute distances", "G90\n" + _F),
    Entry(
        "G90.1", "read", "absolute arc centres: I J are program coordinates (both needed)", "G90.1\nG2 X2 I1 J0 F100\n"
    ),
    Entry("G91", "read", "incremental distances", "G91\n" + _F),
    Entry("G91.1", "read", "incremental arc centres: I J from the arc's start (the start)", "G91.1\n" + _F),
    Entry("G92", "read", "offset making the current point X Y, in every system", "G92 X0 Y0\n" + _F),
    Entry("G92.1", "read", "clear the G92 offset and its parameters", "G92 X1\nG92.1\n" + _F),
    Entry("G92.2", "read", "suspend the G92 offset (parameters kept)", "G92 X1\nG92.2\n" + _F),
    Entry("G92.3", "read", "restore the G92 offset from its parameters", "G92 X1\nG92.2\nG92.3\n" + _F),
    Entry("G93", "read", "inverse time: F on every feed move, the move takes 60 / F s", "G93 G1 X1 F2\n"),
    Entry("G94", "read", "feed per minute (the start)", "G94\n" + _F),
    Entry("G95", "read", "feed per revolution: F times the spindle speed S (rpm) per minute", "G95 S1000 G1 X1 F0.1\n"),
    Entry("G96", "dropped", "spindle speed mode", "G96 S100\n" + _F),
    Entry("G97", "read", "spindle speed in rpm: nothing to do", "G97\n" + _F),
    Entry("G98", "read", "cycle retract to the start Z: nothing to do in XY", "G98\n" + _F),
    Entry("G99", "read", "cycle retract to R: nothing to do in XY", "G99\n" + _F),
    *(
        Entry(code, "refused", "probing: the twin has no probe input", f"{code} X1 F100\n")
        for code in ("G38.2", "G38.3", "G38.4", "G38.5")
    ),  # fmt: skip
    Entry("other G codes", "refused", "unsupported G code", "G6 X1\n"),
    Entry("M0 M1", "read", "pause: the twin runs on", "M0\nM1\n" + _F),
    Entry("M2 M30", "read", "end of program", _F + "M2\nG1 X500\n"),
    Entry("M3 M4 M5", "dropped", "spindle", "M3\n" + _F),
    Entry("M6", "read", "select the tool T (for cutter compensation's D)", "T1 M6\n" + _F),
    Entry("M61", "read", "the loaded tool is Q, no change (for cutter compensation's D)", "M61 Q1\n" + _F),
    Entry("M7 M8 M9", "dropped", "coolant", "M8\n" + _F),
    Entry(
        "M70 M71 M72 M73", "read", "save, forget, restore, restore-on-return the modal state", "M70\nG20\nM72\n" + _F
    ),  # fmt: skip
    Entry("other M codes", "refused", "unsupported M code", "M100\n"),
    Entry("X Y", "read", "axis words", _F),
    Entry("Z A B C U V W", "dropped", "axis", "G1 X1 Z1 F100\n"),
    Entry(
        "@ ^",
        "read",
        "polar: radius, angle in degrees, about the program's XY zero (G91: added to the current point's)",
        "G1 @1 ^45 F100\n",
    ),  # fmt: skip
    Entry(
        "I J R",
        "read",
        "arc centre (G91.1: from the start; G90.1: absolute) or radius; spline control points",
        "G2 X2 I1 F100\n",
    ),
    Entry("K", "refused", "not used in the XY plane", "G2 X1 I1 K1 F100\n"),
    Entry("F", "read", "feed, units per minute", _F),
    Entry("S", "read", "spindle speed, rpm: only G95's feed uses it (the gantry has no spindle)", "S1000\n" + _F),
    Entry("$", "dropped", "spindle number", "$0\n" + _F),
    Entry("T", "read", "tool number (M6 selects it)", "T2\n" + _F),
    Entry("H", "dropped", "tool length offset", "H1\n" + _F),
    Entry(
        "D (G41 / G42: a tool; G41.1 / G42.1: a diameter)",
        "read",
        "the tool, or the diameter, that cutter radius compensation offsets by",
        "G41.1 D0 G1 X1 F100\nG40 X2\n",
    ),  # fmt: skip
    Entry(
        "L P Q",
        "read",
        "G10's level and system, dwell time, arc turns, G64's tolerances, cycle repeats, spline points, NURBS order",
        _F,
    ),  # fmt: skip
    Entry("N", "read", "line number", "N10 " + _F),
    Entry(
        "#n, n 1 to 5601",
        "read",
        "numbered parameters (unset: 0); 5221-5389 the work offsets, 5211-5212 G92's; #5599 (1 at the start): "
        "(debug, ...) shown while above 0",
        "#1000=2\n#5599=0\nG1 X#1000 F100\n",
    ),  # fmt: skip
    Entry(
        "#n, n 5400-5413, 5420-5428",
        "read",
        "read-only: 5400 the tool, 5420-5421 the current X Y (the others: 0)",
        "G1 X[#5420+1] F100\n",
    ),  # fmt: skip
    Entry(
        "#<name>", "read", "named local parameter (one set per call level; unset: an error)", "#<a>=1\nG1 X#<a> F100\n"
    ),  # fmt: skip
    Entry(
        "#<_name>",
        "read",
        "named global parameter; read-only _x _y _metric _imperial _absolute _incremental "
        "_coord_system _feed _current_tool _selected_tool _line _call_level _motion_mode",
        "#<_a>=1\nG1 X[#<_a>+#<_x>] F100\n",
    ),  # fmt: skip
    Entry("#n=value", "read", "a setting takes effect after its line", "#1000=1 G1 X#1000 F100\n"),
    Entry(
        "[ ]",
        "read",
        "expression: ** ; * / MOD ; + - ; EQ NE GT GE LT LE ; AND OR XOR (tightest first)",
        "G1 X[1+2*3 MOD 4] F100\n",
    ),  # fmt: skip
    Entry(
        "functions",
        "read",
        "ABS ACOS ASIN ATAN[y]/[x] COS EXP FIX FUP LN ROUND SIN SQRT TAN EXISTS (degrees)",
        "G1 X[ATAN[1]/[1]/45] F100\n",
    ),  # fmt: skip
    Entry(
        "O sub endsub call return",
        "read",
        "subroutines: arguments in parameters 1-30, a value in #<_value>; NAME.ngc on the subroutine path",
        "o<s> sub\nG1 X#<_a> F100\no<s> endsub\n#<_a>=2\no<s> call [2]\n",
    ),  # fmt: skip
    Entry("O if elseif else endif", "read", "branches", "o1 if [1]\n" + _F + "o1 endif\n"),
    Entry(
        "O while endwhile, do while",
        "read",
        "loops",
        "#1000=0\no1 while [#1000 LT 1]\n#1000=1\n" + _F + "o1 endwhile\n",
    ),
    Entry("O repeat endrepeat", "read", "a loop N times", "o1 repeat [2]\nG91 " + _F + "o1 endrepeat\n"),
    Entry(
        "O break continue",
        "read",
        "leave or restart the loop of their label",
        "o1 repeat [2]\n" + _F + "o1 break\no1 endrepeat\n",
    ),  # fmt: skip
    Entry("/", "read", "block delete: the line is skipped (on by default; contour.block_delete)", "/G1 X9\n" + _F),
    Entry("( ) ;", "read", "comments; (print, ...) (debug, ...) (msg, ...) are shown", "(print, hi) ; c\n" + _F),
    Entry("%", "read", "program delimiters", "%\n" + _F + "%\n"),
)


def dialect_table() -> str:
    """The Markdown table of docs/gcode.md's dialect section."""
    rows = ["| word or construct | status | what it does here, or why it is refused |", "|---|---|---|"]
    rows += [f"| `{e.word}` | {e.status} | {e.what} |" for e in DIALECT]
    return "\n".join(rows)
