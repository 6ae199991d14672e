"""LinuxCNC's own interpreter as the oracle: the project's programs (tests/data/rs274/, written here from
LinuxCNC's documentation) through ``rs274 -g`` and through the twin's reader give the same XY end points.

Each corner of the dialect has a program: work offsets and G92 with G91, rotation (G10 L2 R), polar in
G90 and G91, arcs by R of both signs and by I J in G91.1 and G90.1 with P turns and ends off the circle,
splines, canned cycles with L, subroutines and loops, cutter compensation with a tool table, an inch
program, the feed modes. rs274 prints the moves in work coordinates and the offsets apart; the
comparison (:mod:`gantry_twin.gcode.oracle`) composes them as LinuxCNC's canon does and walks both paths
within 1 um (3 um in inches). Skipped, with the reason, where rs274 is not installed.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from gantry_twin.gcode import read_program
from gantry_twin.gcode.oracle import Point, compare, rs274_available, rs274_path, run_rs274, twin_path
from gantry_twin.gcode.tools import read_tool_table

DATA = Path(__file__).parent / "data" / "rs274"
PROGRAMS = sorted(p.name for p in DATA.glob("*.ngc"))
needs_rs274 = pytest.mark.skipif(
    rs274_available() is None, reason="rs274 (LinuxCNC's interpreter, Debian linuxcnc-uspace) is not installed"
)


def inch_table(tmp_path: Path) -> Path:
    """tools.tbl (mm, the twin's machine units) for rs274, whose standalone machine units are inches."""
    tools = read_tool_table(DATA / "tools.tbl")
    path = tmp_path / "tools_in.tbl"
    path.write_text("".join(f"T{t.number} P{t.pocket} D{t.diameter_m / 0.0254!r}\n" for t in tools.values()))
    return path


def both(name: str, tmp_path: Path):
    """rs274's path and the reader's, for one program of tests/data/rs274."""
    program = DATA / name
    table = DATA / "tools.tbl" if "compensation" in name else None
    code, output = run_rs274(program, inch_table(tmp_path) if table else None)
    oracle = rs274_path(code, output)
    assert oracle.ok, f"rs274 refused {name}: {oracle.message}"
    tools = read_tool_table(table) if table else None
    twin = read_program(program, drop_unsupported=True, tools=tools, merge_lines=False)
    return oracle, twin


def test_the_programs_cover_every_corner_the_issue_lists():
    assert PROGRAMS == ["arcs.ngc", "compensation.ngc", "cycles.ngc", "feeds.ngc", "inch.ngc", "offsets.ngc",
                        "polar.ngc", "rotation.ngc", "splines.ngc", "subroutines.ngc"]  # fmt: skip


@needs_rs274
@pytest.mark.parametrize("name", PROGRAMS)
def test_the_reader_gives_rs274s_xy_end_points(name, tmp_path):
    oracle, twin = both(name, tmp_path)
    assert oracle.xy_plane and not oracle.foreign
    result = compare(oracle.points, twin_path(twin))
    assert result.agreed, f"{name}: {result.disagreement}"
    assert result.matched > 5  # the program moves in XY
    assert result.worst_mm <= 1e-3 if name != "inch.ngc" else result.worst_mm <= 3e-3


@needs_rs274
@pytest.mark.parametrize(
    ("name", "change"),
    [
        ("polar.ngc", lambda s: s.replace("G1 @2 ^30", "G1 @2 ^31")),  # a changed angle
        ("arcs.ngc", lambda s: s.replace("I-10 J0 P3", "I-10 J0 P2")),  # a turn less
        ("arcs.ngc", lambda s: s.replace("G91 G2 X10 Y10 R10", "G91 G2 X10 Y10 R-10")),  # the long way round
        ("rotation.ngc", lambda s: s.replace("R30", "R30.01")),  # the rotation by 0.01 deg: 9 um at 50 mm
    ],
)
def test_the_comparison_sees_a_changed_program(name, change, tmp_path):
    """The oracle can fail: rs274 on the original, the reader on a program changed by a little."""
    oracle, _ = both(name, tmp_path)
    changed = tmp_path / name
    changed.write_text(change((DATA / name).read_text()))
    twin = read_program(changed, drop_unsupported=True, merge_lines=False)
    assert not compare(oracle.points, twin_path(twin)).agreed


def test_the_walk_drops_z_only_motion_and_takes_a_splines_end_from_the_reader():
    rs = (Point("rapid", 0.0, 0.0), Point("line", 10.0, 0.0), Point("line", 10.0, 0.0), Point("spline", None, None),
          Point("line", 20.0, 5.0))  # fmt: skip
    twin = (Point("start", 0.0, 0.0), Point("line", 10.0, 0.0), Point("line", 14.0, 3.0), Point("line", 20.0, 5.0))
    assert compare(rs, twin).agreed
    off = dataclasses.replace(twin[3], x=20.0011)
    result = compare(rs, (*twin[:3], off))
    assert not result.agreed and "(1.1 um)" in result.disagreement
    assert not compare(rs[:3], twin).agreed  # the reader has moves rs274 has not


def test_rs274s_offsets_compose_as_linuxcncs_canon():
    """machine = rotate(work + G92, rotation) + G5x, in the units in force when rs274 printed them."""
    output = "\n".join([
        "    1 N..... USE_LENGTH_UNITS(CANON_UNITS_INCHES)",
        "    2 N..... SET_G5X_OFFSET(1, 1.0000, 2.0000, 0.0000, 0.0000, 0.0000, 0.0000)",
        "    3 N..... SET_G92_OFFSET(0.5000, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000)",
        "    4 N..... SET_XY_ROTATION(90.0000)",
        "    5 N..... STRAIGHT_FEED(1.0000, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000)",
    ])  # fmt: skip
    (point,) = rs274_path(0, output).points
    assert (point.x, point.y, point.unit) == (pytest.approx(25.4), pytest.approx(2.0 * 25.4 + 1.5 * 25.4), "in")


@needs_rs274
def test_the_study_tool_classes_each_program_of_a_checkout(tmp_path, capsys):
    """tools/rs274_study.py on a checkout of four programs: two agree, one is in another plane, one rs274
    stops (no program end); exit 0 (none differs)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("rs274_study", Path(__file__).parents[1] / "tools/rs274_study.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    files = tmp_path / "checkout" / "nc_files"
    files.mkdir(parents=True)
    for name in ("polar.ngc", "rotation.ngc"):
        (files / name).write_text((DATA / name).read_text())
    (files / "xz.ngc").write_text("G18 G0 X0 Z0\nG2 X10 Z0 I5 K0 F100\nM2\n")
    (files / "sub.ngc").write_text("o<sub> sub\nG1 X1 F1\no<sub> endsub\n")
    assert study.main([str(tmp_path / "checkout"), "--list"]) == 0
    out = capsys.readouterr().out
    assert "4 programs: agree 2, not XY 1, rs274 stops 1" in out
    assert "not XY         nc_files/xz.ngc: arcs in another plane" in out
